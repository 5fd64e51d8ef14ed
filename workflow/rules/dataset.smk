# Pair manifests results/datasets/{variant}/pairs.jsonl (contract: docs/architecture.md).
# Only variants whose data stages exist have a rule here; each appends itself to
# DATASET_VARIANTS, which constrains the refiner's {variant} wildcard (include this file
# before refiner.smk). full / no_real / no_synthetic plug in as rules when their stages exist.


rule dataset_clean_buffers:
    input:
        clean_buffers_inputs,
    output:
        pairs=f"{OUT}/datasets/clean_buffers/pairs.jsonl",
    log:
        "logs/dataset/clean_buffers.log",
    benchmark:
        "logs/benchmark/dataset/clean_buffers.tsv"
    conda:
        "../../envs/refiner.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,
    params:
        script=script_path("build_dataset.py"),
        plans=refiner_plans_json,
    shell:
        "python {params.script} --variant clean_buffers "
        "--plans-json {params.plans:q} --output {output.pairs} > {log} 2>&1"
