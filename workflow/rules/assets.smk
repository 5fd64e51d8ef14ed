# Assets: procedural "Objaverse-style" GLBs (or a user folder), then curation.


def curation_inputs(wildcards):
    if config["assets"]["source"] == "procedural":
        return f"{OUT}/assets/raw/generated.json"
    return []


def curation_source_dir():
    if config["assets"]["source"] == "procedural":
        return f"{OUT}/assets/raw"
    return config["assets"]["dir"]


rule generate_assets:
    output:
        f"{OUT}/assets/raw/generated.json",
    params:
        out_dir=f"{OUT}/assets/raw",
        settings=as_json(config["assets"].get("procedural", {"count": 6})),
    log:
        "logs/generate_assets.log",
    benchmark:
        "benchmarks/generate_assets.tsv"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=30,
    shell:
        "{PY} {workflow.basedir}/scripts/generate_assets.py --out-dir {params.out_dir} "
        "--listing {output} --seed {SEED} --settings {params.settings:q} > {log} 2>&1"


rule curate_assets:
    input:
        curation_inputs,
    output:
        manifest=f"{OUT}/assets/manifest.json",
    params:
        src_dir=curation_source_dir(),
        out_dir=f"{OUT}/assets/curated",
        settings=as_json(config["assets"].get("curation", {})),
    log:
        "logs/curate_assets.log",
    benchmark:
        "benchmarks/curate_assets.tsv"
    threads: 1
    resources:
        mem_mb=4000,
        runtime=120,
    shell:
        "{PY} {workflow.basedir}/scripts/curate_assets.py --src-dir {params.src_dir} "
        "--out-dir {params.out_dir} --manifest {output.manifest} --settings {params.settings:q} > {log} 2>&1"
