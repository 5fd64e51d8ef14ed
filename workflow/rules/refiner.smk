# Refiner: training per dataset variant, inference on the held-out split, evaluation.
# Config: config["refiner"] is the refiner config dict (keys: lightcrafter/refiner/config.py
# KEY_DOCS) plus "resources" {threads, mem_mb, runtime} used by these rules only.
# {variant} is constrained to DATASET_VARIANTS (dataset.smk): variants without a dataset rule
# cannot be requested, and new ones plug in by adding their dataset rule there.


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
