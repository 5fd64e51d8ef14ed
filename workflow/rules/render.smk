# Ground truth with Blender Cycles, one scene per process. Buffers do not depend on lighting:
# one job per trajectory. Radiance: one job per (trajectory, lighting that some pair uses).


rule render_buffers:
    input:
        scene=L.scene_spec("{scene}"),
        manifest=L.assets_manifest(),
    output:
        buffers=L.gt_clip_manifest("{scene}", "{traj}"),
    log:
        "logs/render_buffers/{scene}_{traj}.log",
    benchmark:
        "logs/benchmark/render_buffers/{scene}_{traj}.tsv"
    conda:
        "../../envs/blender.yaml"
    threads: 1
    resources:
        **blender_resources(),
        mem_mb=3000,
        runtime=60,
    params:
        **script_params("render_gt.py"),
        out_dir=trajectory_dir,
        device=config["render"]["device"],
    shell:
        "python {params.script} --scene {input.scene} --traj {wildcards.traj} "
        "--buffers {params.out_dir} --threads {threads} --device {params.device} > {log} 2>&1"


rule render_rgb:
    input:
        scene=L.scene_spec("{scene}"),
        manifest=L.assets_manifest(),
    output:
        frames=L.gt_rgb("{scene}", "{traj}", "{light}") + ".json",
        preview=report(
            L.gt_rgb("{scene}", "{traj}", "{light}") + ".mp4",
            category="Ground truth",
            labels={"scene": "{scene}", "trajectory": "{traj}", "lighting": "{light}"},
        ),
    log:
        "logs/render_rgb/{scene}_{traj}_{light}.log",
    benchmark:
        "logs/benchmark/render_rgb/{scene}_{traj}_{light}.tsv"
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
        "python {params.script} --scene {input.scene} --traj {wildcards.traj} "
        "--light {wildcards.light} --out {params.out_dir} --threads {threads} --device {params.device} > {log} 2>&1"


rule summarize_ground_truth:
    input:
        specs=[L.scene_spec(s) for s in rendered_scenes()],
        buffers=gt_buffer_manifests(),
        rgb=gt_rgb_manifests(),
    output:
        report(L.summary("ground_truth"), category="Ground truth"),
    log:
        "logs/summarize_ground_truth.log",
    benchmark:
        "logs/benchmark/summarize_ground_truth.tsv"
    conda:
        "../../envs/assets.yaml"
    threads: 1
    resources:
        mem_mb=500,
        runtime=5,
    params:
        **script_params("summarize_gt.py"),
        gt_root=gt_root_of_inputs,
    shell:
        "python {params.script} --gt-root {params.gt_root} --specs {input.specs} "
        "--out {output} > {log} 2>&1"
