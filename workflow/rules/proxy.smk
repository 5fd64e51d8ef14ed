# Forward renderer R (Mitsuba 3) on GROUND-TRUTH buffers: the clean_buffers dataset variant and the
# Cycles cross-check (benchmarks/proxy_vs_cycles.py). One job per (trajectory, lighting).


rule render_proxy_gt:
    input:
        buffers=f"{OUT}/gt/{{scene}}/{{traj}}/buffers.json",
        scene=f"{OUT}/scenes/{{scene}}/scene.json",
    output:
        manifest=f"{OUT}/proxy_gt/{{scene}}/{{traj}}/{{light}}.json",
        preview=report(
            f"{OUT}/proxy_gt/{{scene}}/{{traj}}/{{light}}.mp4",
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
        script=script_path("render_proxy.py"),
        out_dir=manifest_stem,
        spp=config["proxy"]["spp"],
        visibility=config["proxy"]["visibility"],
        rel_threshold=config["proxy"]["rel_threshold"],
    shell:
        "python {params.script} --clip {input.buffers} "
        "--scene {input.scene} --traj {wildcards.traj} --light {wildcards.light} --out {params.out_dir} "
        "--spp {params.spp} --visibility {params.visibility} --rel-threshold {params.rel_threshold} "
        "--threads {threads} > {log} 2>&1"
