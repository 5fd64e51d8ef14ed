# Long-form check (the paper's "Long-Form Consistent Relighting"): one long trajectory of the first test
# scene, rendered by Cycles under a target light, its proxy by R, refined by the full model with
# overlap-fused tiling and with independent chunks; per-frame temporal difference and Warp-SSIM.


rule longform_scene:
    input:
        manifest=L.assets_manifest(),
    output:
        L.longform_spec(),
    log:
        "logs/longform/scene.log",
    benchmark:
        "logs/benchmark/longform/scene.tsv"
    conda:
        "../../envs/assets.yaml"
    threads: 1
    resources:
        mem_mb=500,
        runtime=5,
    params:
        **script_params("sample_scene.py"),
        scene=LONGFORM["scene"],
        cfg=params_file(LONGFORM["config"]),
    shell:
        "python {params.script} --scene-id {params.scene} --manifest {input.manifest} "
        "--config {params.cfg} --out {output} > {log} 2>&1"


rule longform_buffers:
    input:
        scene=L.longform_spec(),
        manifest=L.assets_manifest(),
    output:
        L.longform_clip_manifest("t0"),
    log:
        "logs/longform/buffers.log",
    benchmark:
        "logs/benchmark/longform/buffers.tsv"
    conda:
        "../../envs/blender.yaml"
    threads: 1
    resources:
        **blender_resources(),
        mem_mb=3000,
        runtime=60,
    params:
        **script_params("render_gt.py"),
        out_dir=parent_dir,
        device=config["render"]["device"],
    shell:
        "python {params.script} --scene {input.scene} --traj t0 --buffers {params.out_dir} "
        "--threads {threads} --device {params.device} > {log} 2>&1"


rule longform_rgb:
    input:
        scene=L.longform_spec(),
        manifest=L.assets_manifest(),
    output:
        L.longform_rgb("t0", "{light}") + ".json",
    log:
        "logs/longform/rgb_{light}.log",
    benchmark:
        "logs/benchmark/longform/rgb_{light}.tsv"
    conda:
        "../../envs/blender.yaml"
    threads: 1
    resources:
        **blender_resources(),
        mem_mb=3000,
        runtime=120,
    params:
        **script_params("render_gt.py"),
        out_dir=trajectory_dir,
        device=config["render"]["device"],
    shell:
        "python {params.script} --scene {input.scene} --traj t0 --light {wildcards.light} "
        "--out {params.out_dir} --threads {threads} --device {params.device} > {log} 2>&1"


rule longform_proxy:
    input:
        clip=L.longform_clip_manifest("t0"),
        scene=L.longform_spec(),
    output:
        L.longform_proxy("{light}") + ".json",
    log:
        "logs/longform/proxy_{light}.log",
    benchmark:
        "logs/benchmark/longform/proxy_{light}.tsv"
    conda:
        "../../envs/mitsuba.yaml"
    threads: 1
    resources:
        mem_mb=3000,
        runtime=30,
    params:
        **script_params("render_proxy.py"),
        out_dir=manifest_stem,
        proxy=proxy_settings(),
    shell:
        "python {params.script} --clip {input.clip} --scene {input.scene} --traj t0 "
        "--light {wildcards.light} --out {params.out_dir} --proxy {params.proxy} --threads {threads} > {log} 2>&1"


rule longform:
    input:
        model=L.refiner_model(LONGFORM["variant"]),
        proxy=L.longform_proxy(LONGFORM["light"]) + ".json",
        target=L.longform_rgb("t0", LONGFORM["light"]) + ".json",
    output:
        L.longform_metrics(),
    log:
        "logs/longform/check.log",
    benchmark:
        "logs/benchmark/longform/check.tsv"
    conda:
        "../../envs/refiner.yaml"
    threads: refiner_threads()
    resources:
        mem_mb=4000,
        runtime=60,
    params:
        **script_params("longform.py"),
        proxy=lambda wc, input: str(Path(input.proxy).with_suffix("")),
        target=lambda wc, input: str(Path(input.target).with_suffix("")),
        out_dir=parent_dir,
    shell:
        "python {params.script} --model {input.model} --proxy {params.proxy} --target {params.target} "
        "--out {params.out_dir} --threads {threads} > {log} 2>&1"
