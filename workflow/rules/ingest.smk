# MIT Multi-Illumination (relight_mit): the source image's scene state rendered under the map fitted to the
# captured target image (lightcrafter.mit_multi_illum).
# Real videos -> real pseudo-pairs: ingest a clip (linear frames at the training size), run the same
# Phi as the synthetic branch, fit the source environment map (lightcrafter.envfit), which also renders
# the pseudo-input R(S, L_hat) of every frame: the pair's proxy.


rule ingest_video:
    output:
        frames=L.real_frames("{clip}") + ".json",
    log:
        "logs/ingest/{clip}.log",
    benchmark:
        "logs/benchmark/ingest/{clip}.tsv"
    conda:
        "../../envs/recon.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    params:
        **script_params("ingest_video.py"),
        clip=real_clip_file,
        out_dir=manifest_stem,
        width=config["scenes"]["width"],
        height=config["scenes"]["height"],
        frames=real_num_frames,
        short=config["real"]["short_clips"],
    shell:
        "python {params.script} --clip-json {params.clip} --clip-id {wildcards.clip} --out {params.out_dir} "
        "--width {params.width} --height {params.height} --num-frames {params.frames} "
        "--short-clips {params.short} > {log} 2>&1"


rule reconstruct_real:
    input:
        video=L.real_frames("{clip}") + ".json",
        estimator=estimator_input,
    output:
        clip=L.recon_clip_manifest("real", "{clip}"),
    log:
        "logs/recon/real_{clip}.log",
    benchmark:
        "logs/benchmark/recon/real_{clip}.tsv"
    # ahead of the renders: the real clips' Phi and envmap fits gate the trainings that use real pairs, and
    # without it the default run left one real clip's Phi until 11 min in (its trainings then ran last)
    priority: 10
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
        settings=real_recon_settings,
        static=real_scene_static,
        skip=skip_failed_flag(),
    shell:
        "python {params.script} --frames {input.video} --out {params.out_dir} {params.backend} "
        "{params.estimator} "
        "--scene-static {params.static} --settings-json {params.settings} --name {wildcards.clip} "
        "{params.skip} > {log} 2>&1"


rule fit_envmap:
    input:
        clip=L.recon_clip_manifest("real", "{clip}"),
        video=L.real_frames("{clip}") + ".json",
    output:
        fit=L.envfit_manifest("{clip}"),
        pseudo=L.pseudo_input("{clip}") + ".json",
    log:
        "logs/envfit/{clip}.log",
    benchmark:
        "logs/benchmark/envfit/{clip}.tsv"
    priority: 10  # as reconstruct_real
    conda:
        "../../envs/mitsuba.yaml"
    threads: 1  # Dr.Jit gains little from a second thread: two fits side by side took 23-26 s, one after the other
    # on two threads each 42-46 s (same fitted parameters)
    resources:
        mem_mb=4000,
        runtime=30,
    params:
        **script_params("fit_envmap.py"),
        clip_dir=clip_dir_of_input,
        out_dir=parent_dir,
        frames=manifest_stem_of_input,
        settings=params_file(config["envfit"]),
        proxy=proxy_settings(),
    shell:
        "python {params.script} --clip {params.clip_dir} --frames {params.frames} --out {params.out_dir} "
        "--proxy {params.proxy} --settings-json {params.settings} --threads {threads} > {log} 2>&1"


# A MIT pair id (mit_<scene>_d<i>_to_d<j>) also matches {clip}: its fit comes from relight_mit.
ruleorder: relight_mit > fit_envmap


rule relight_mit:
    input:
        clip=lambda wc: L.recon_clip_manifest("real", mit_pair(wc)["source"]),
        video=lambda wc: L.real_frames(mit_pair(wc)["target"]) + ".json",
    output:
        fit=L.envfit_manifest("{pair}"),
        pseudo=L.pseudo_input("{pair}") + ".json",
    log:
        "logs/envfit/{pair}.log",
    benchmark:
        "logs/benchmark/envfit/{pair}.tsv"
    conda:
        "../../envs/mitsuba.yaml"
    threads: 1
    resources:
        mem_mb=4000,
        runtime=30,
    params:
        **script_params("fit_envmap.py"),
        clip_dir=clip_dir_of_input,
        out_dir=parent_dir,
        frames=manifest_stem_of_input,
        settings=params_file(config["envfit"]),
        proxy=proxy_settings(),
    shell:
        "python {params.script} --clip {params.clip_dir} --frames {params.frames} --out {params.out_dir} "
        "--proxy {params.proxy} --settings-json {params.settings} --threads {threads} > {log} 2>&1"
