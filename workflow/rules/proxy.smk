# Forward renderer R (Mitsuba 3). One job per (trajectory, target lighting):
#   render_proxy_gt: R on GROUND-TRUTH buffers (clean_buffers variant, the oracle proxy of evaluation);
#   render_proxy:    R on Align(Phi(source video)) buffers, the artifact-matched proxy of the paper.


rule render_proxy_gt:
    input:
        clip=L.gt_clip_manifest("{scene}", "{traj}"),
        scene=L.scene_spec("{scene}"),
    output:
        manifest=L.proxy_gt("{scene}", "{traj}", "{light}") + ".json",
        preview=report(
            L.proxy_gt("{scene}", "{traj}", "{light}") + ".mp4",
            category="Proxy (GT buffers)",
            labels={"scene": "{scene}", "trajectory": "{traj}", "lighting": "{light}"},
        ),
    log:
        "logs/render_proxy_gt/{scene}_{traj}_{light}.log",
    benchmark:
        "logs/benchmark/render_proxy_gt/{scene}_{traj}_{light}.tsv"
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
        "python {params.script} --clip {input.clip} "
        "--scene {input.scene} --traj {wildcards.traj} --light {wildcards.light} --out {params.out_dir} "
        "--proxy {params.proxy} --threads {threads} > {log} 2>&1"


rule render_proxy:
    input:
        clip=L.aligned_clip_manifest("{scene}", "{traj}"),
        scene=L.scene_spec("{scene}"),
    output:
        manifest=L.proxy("{scene}", "{traj}", "{light}") + ".json",
    log:
        "logs/render_proxy/{scene}_{traj}_{light}.log",
    benchmark:
        "logs/benchmark/render_proxy/{scene}_{traj}_{light}.tsv"
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
        "python {params.script} --clip {input.clip} "
        "--scene {input.scene} --traj {wildcards.traj} --light {wildcards.light} --out {params.out_dir} "
        "--proxy {params.proxy} --threads {threads} > {log} 2>&1"
