# Scene specs: one declarative scene.json per scene id, a pure function of (config, seed, id).


rule sample_scene:
    input:
        manifest=f"{OUT}/assets/manifest.json",
    output:
        f"{OUT}/scenes/{{scene}}/scene.json",
    params:
        cfg=as_json({"seed": SEED, "scenes": config["scenes"], "render": config["render"]}),
    log:
        "logs/sample_scene/{scene}.log",
    benchmark:
        "benchmarks/sample_scene/{scene}.tsv"
    threads: 1
    resources:
        mem_mb=500,
        runtime=5,
    shell:
        "{PY} {workflow.basedir}/scripts/sample_scene.py --scene-id {wildcards.scene} "
        "--manifest {input.manifest} --config {params.cfg:q} --out {output} > {log} 2>&1"
