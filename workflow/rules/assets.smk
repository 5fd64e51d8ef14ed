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
        **script_params("generate_assets.py"),
        out_dir=parent_dir,
        seed=SEED,
        settings=params_file(config["assets"]["procedural"]),
    shell:
        "python {params.script} --out-dir {params.out_dir} "
        "--listing {output} --seed {params.seed} --settings {params.settings} > {log} 2>&1"


# Curation as assets.curation_jobs jobs (a SLURM job array), each every n-th GLB; each asset's result is
# kept beside its GLB, so a rerun redoes only unfinished assets. curate_assets joins the shards.
rule curate_assets_shard:
    input:
        curation_inputs,
    output:
        f"{OUT}/assets/shards/{{shard}}.json",
    log:
        "logs/curate_assets/{shard}.log",
    benchmark:
        "logs/benchmark/curate_assets/{shard}.tsv"
    conda:
        "../../envs/assets.yaml"
    threads: 1
    resources:
        mem_mb=4000,
        runtime=120,
    params:
        **script_params("curate_assets.py"),
        src_dir=curation_source_dir(),
        out_dir=str(Path(L.assets_manifest()).parent / "curated"),
        shards=CURATION_JOBS,
        settings=params_file(config["assets"]["curation"]),
    shell:
        "python {params.script} --src-dir {params.src_dir} --out-dir {params.out_dir} --manifest {output} "
        "--shard {wildcards.shard} --shards {params.shards} --settings {params.settings} > {log} 2>&1"


rule curate_assets:
    input:
        [f"{OUT}/assets/shards/{k}.json" for k in range(CURATION_JOBS)],
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
        mem_mb=1000,
        runtime=10,
    params:
        **script_params("curate_assets.py"),
    shell:
        "python {params.script} --merge {input} --manifest {output.manifest} > {log} 2>&1"
