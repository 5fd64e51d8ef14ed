# Refiner: training per dataset variant, inference on the held-out split, evaluation.
# Config: config["refiner"] is the refiner config dict (keys: lightcrafter/refiner/config.py
# KEY_DOCS) plus "resources" {threads, mem_mb, runtime} used by these rules only.
# {variant} is constrained to DATASET_VARIANTS (dataset.smk): variants without a dataset rule
# cannot be requested, and new ones plug in by adding their dataset rule there.


wildcard_constraints:
    variant="|".join(DATASET_VARIANTS),


def refiner_model_config():
    """The refiner config dict passed to the scripts (the workflow-only 'resources' key removed)."""
    return {k: v for k, v in config.get("refiner", {}).items() if k != "resources"}


def refiner_config_json(wildcards):
    return as_json(refiner_model_config())


def refiner_infer_json(wildcards):
    """Inference overrides applied on top of the config stored with the trained model."""
    return as_json({"infer": refiner_model_config().get("infer", {})})


def refiner_resource(key, default):
    return config.get("refiner", {}).get("resources", {}).get(key, default)


def refiner_threads():
    return refiner_resource("threads", 2)


def refiner_pairs(wildcards):
    return f"{OUT}/datasets/{wildcards.variant}/pairs.jsonl"


def refiner_outputs():
    """Evaluation outputs of every dataset variant that exists."""
    return [f"{OUT}/eval/{v}/metrics.json" for v in DATASET_VARIANTS]


rule train_refiner:
    input:
        pairs=refiner_pairs,
    output:
        model=f"{OUT}/refiner/{{variant}}/model.pt",
    log:
        "logs/refiner/train_{variant}.log",
    benchmark:
        "logs/benchmark/refiner/train_{variant}.tsv"
    conda:
        "../../envs/refiner.yaml"
    threads: refiner_threads()
    resources:
        mem_mb=refiner_resource("mem_mb", 4000),
        runtime=refiner_resource("runtime", 120),
    params:
        script=script_path("train_refiner.py"),
        cfg=refiner_config_json,
        out_dir=f"{OUT}/refiner/{{variant}}",
    shell:
        "python {params.script} --pairs {input.pairs} "
        "--config-json {params.cfg:q} --out {params.out_dir} --threads {threads} > {log} 2>&1"


rule infer_refiner:
    input:
        model=f"{OUT}/refiner/{{variant}}/model.pt",
        pairs=refiner_pairs,
    output:
        manifest=f"{OUT}/refined/{{variant}}/manifest.json",
    log:
        "logs/refiner/infer_{variant}.log",
    benchmark:
        "logs/benchmark/refiner/infer_{variant}.tsv"
    conda:
        "../../envs/refiner.yaml"
    threads: refiner_threads()
    resources:
        mem_mb=refiner_resource("mem_mb", 4000),
        runtime=refiner_resource("runtime", 120),
    params:
        script=script_path("infer_refiner.py"),
        cfg=refiner_infer_json,
        out_dir=f"{OUT}/refined/{{variant}}",
    shell:
        "python {params.script} --model {input.model} --pairs {input.pairs} "
        "--split test --config-json {params.cfg:q} --out {params.out_dir} --threads {threads} > {log} 2>&1"


rule evaluate_refiner:
    input:
        pairs=refiner_pairs,
        refined=f"{OUT}/refined/{{variant}}/manifest.json",
    output:
        metrics=f"{OUT}/eval/{{variant}}/metrics.json",
    log:
        "logs/refiner/evaluate_{variant}.log",
    benchmark:
        "logs/benchmark/refiner/evaluate_{variant}.tsv"
    conda:
        "../../envs/refiner.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=30,
    params:
        script=script_path("evaluate_refiner.py"),
        exposure=config.get("refiner", {}).get("data", {}).get("exposure_ev", 0.0),
    shell:
        "python {params.script} --pairs {input.pairs} "
        "--refined {input.refined} --split test --exposure-ev {params.exposure} "
        "--out {output.metrics} > {log} 2>&1"
