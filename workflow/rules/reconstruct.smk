# The reconstruction stack Phi (lightcrafter.recon): the G-buffer estimator trained on the recon split,
# Phi run ONCE per synthetic trajectory on its source-light video (not per target light), and Align
# into the ground-truth frame (synthetic only; a global similarity and a depth scale).


rule train_gbuffer_estimator:
    input:
        unpack(estimator_training_inputs),
    output:
        model=L.estimator(),
        curve=report(L.estimator_curve(), category="Reconstruction"),
    log:
        "logs/recon/train_gbuffer_estimator.log",
    benchmark:
        "logs/benchmark/recon/train_gbuffer_estimator.tsv"
    conda:
        "../../envs/refiner.yaml"
    threads: 2
    resources:
        mem_mb=4000,
        runtime=60,
    params:
        **script_params("train_estimator.py"),
        cfg=params_file(dict(config["recon"]["estimator"], threads=2)),
    shell:
        "python {params.script} --clips {input.clips} --videos {input.videos} "
        "--config-json {params.cfg} --out {output.model} --curve {output.curve} > {log} 2>&1"


rule reconstruct_synthetic:
    input:
        video=source_video,
        estimator=estimator_input,
    output:
        clip=L.recon_clip_manifest("synthetic", "{scene}_{traj}"),
    log:
        "logs/recon/synthetic_{scene}_{traj}.log",
    benchmark:
        "logs/benchmark/recon/synthetic_{scene}_{traj}.tsv"
    conda:
        "../../envs/recon.yaml"
    threads: 1
    resources:
        mem_mb=3000,
        runtime=30,
    params:
        **script_params("reconstruct.py"),
        backend=recon_backend_args(),
        estimator=estimator_arg,
        out_dir=parent_dir,
        fps=config["scenes"]["fps"],
        static=scene_static_flag,
        settings=params_file(recon_settings()),
        skip=skip_failed_flag(),
    shell:
        "python {params.script} --frames {input.video} --out {params.out_dir} {params.backend} "
        "{params.estimator} "
        "--fps {params.fps} --scene-static {params.static} --settings-json {params.settings} "
        "--name {wildcards.scene}_{wildcards.traj} {params.skip} > {log} 2>&1"


rule align_synthetic:
    input:
        est=L.recon_clip_manifest("synthetic", "{scene}_{traj}"),
        gt=L.gt_clip_manifest("{scene}", "{traj}"),
    output:
        clip=L.aligned_clip_manifest("{scene}", "{traj}"),
    log:
        "logs/recon/align_{scene}_{traj}.log",
    benchmark:
        "logs/benchmark/recon/align_{scene}_{traj}.tsv"
    conda:
        "../../envs/recon.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    params:
        **script_params("align_clip.py"),
        out_dir=parent_dir,
    shell:
        "python {params.script} --est {input.est} --gt {input.gt} --out {params.out_dir} > {log} 2>&1"


rule summarize_reconstruction:
    input:
        unpack(synthetic_recon_inputs),
    output:
        report(L.summary("reconstruction"), category="Reconstruction"),
    log:
        "logs/recon/summarize_reconstruction.log",
    benchmark:
        "logs/benchmark/recon/summarize_reconstruction.tsv"
    conda:
        "../../envs/recon.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    params:
        **script_params("summarize_recon.py"),
        plans=plans_file,
        inputs=inputs_file("est", "aligned", "gt", "real"),
    shell:
        "python {params.script} --inputs {params.inputs} --plans-json {params.plans} "
        "--out {output} > {log} 2>&1"
