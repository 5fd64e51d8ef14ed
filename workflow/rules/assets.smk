# Assets: procedural "Objaverse-style" GLBs (or a user folder), then curation.


rule generate_assets:
    output:
        f"{OUT}/assets/raw/generated.json",
    log:
        "logs/generate_assets.log",
    benchmark:
        "logs/benchmark/generate_assets.tsv"
    conda:
        "../../envs/assets.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=30,
    params:
        script=script_path("generate_assets.py"),
        out_dir=parent_dir,
        seed=SEED,
        settings=params_file(config["assets"]["procedural"]),
    shell:
        "python {params.script} --out-dir {params.out_dir} "
        "--listing {output} --seed {params.seed} --settings {params.settings} > {log} 2>&1"


rule curate_assets:
    input:
        curation_inputs,
    output:
        manifest=L.assets_manifest(),
    log:
        "logs/curate_assets.log",
    benchmark:
        "logs/benchmark/curate_assets.tsv"
    conda:
        "../../envs/assets.yaml"
    threads: 1
    resources:
        mem_mb=4000,
        runtime=120,
    params:
        script=script_path("curate_assets.py"),
        src_dir=curation_source_dir(),
        out_dir=curated_dir,
        settings=params_file(config["assets"]["curation"]),
    shell:
        "python {params.script} --src-dir {params.src_dir} "
        "--out-dir {params.out_dir} --manifest {output.manifest} --settings {params.settings} > {log} 2>&1"
