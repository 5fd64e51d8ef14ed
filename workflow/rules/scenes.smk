# Scene specs: one declarative scene.json per scene id, a pure function of (config, seed, id).


rule sample_scene:
    input:
        manifest=L.assets_manifest(),
    output:
        L.scene_spec("{scene}"),
    log:
        "logs/sample_scene/{scene}.log",
    benchmark:
        "logs/benchmark/sample_scene/{scene}.tsv"
    conda:
        "../../envs/assets.yaml"
    threads: 1
    resources:
        mem_mb=500,
        runtime=5,
    params:
        **script_params("sample_scene.py"),
        cfg=params_file(
            {"seed": SEED, "scenes": config["scenes"], "render": config["render"]}
        ),
    shell:
        "python {params.script} --scene-id {wildcards.scene} "
        "--manifest {input.manifest} --config {params.cfg} --out {output} > {log} 2>&1"
