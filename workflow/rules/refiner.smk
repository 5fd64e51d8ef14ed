# Refiner: training per dataset variant (its train split), inference and evaluation on each held-out
# benchmark (shared by all variants). Config: config["refiner"] is the refiner config (models in
# lightcrafter/refiner/config.py) plus "resources" {threads, mem_mb, runtime} for these rules.


rule encode_empty_prompt:
    output:
        emb=L.empty_prompt(),
    log:
        "logs/refiner/encode_empty_prompt.log",
    conda:
        "../../envs/refiner.yaml"
    threads: refiner_threads()
    resources:
        mem_mb=48000,
        runtime=60,
    params:
        **script_params("encode_empty_prompt.py"),
        cfg=lambda wildcards: params_file(refiner_model_config()),
    shell:
        "python {params.script} --config-json {params.cfg} --out {output.emb} > {log} 2>&1"


rule train_refiner:
    input:
        pairs=L.pairs("{variant}"),
        prompt=refiner_prompt_input(),
    output:
        model=L.refiner_model("{variant}"),
    log:
        "logs/refiner/train_{variant}.log",
    benchmark:
        "logs/benchmark/refiner/train_{variant}.tsv"
    priority: variant_priority
    conda:
        "../../envs/refiner.yaml"
    threads: refiner_threads()
    resources:
        mem_mb=refiner_resource("mem_mb"),
        runtime=refiner_resource("runtime"),
    params:
        **script_params("train_refiner.py"),
        cfg=refiner_config_file,
        out_dir=parent_dir,
        launcher=refiner_launcher(),
    shell:
        "{params.launcher} {params.script} --pairs {input.pairs} "
        "--config-json {params.cfg} --out {params.out_dir} --threads {threads} > {log} 2>&1"


rule infer_refiner:
    input:
        model=L.refiner_model("{variant}"),
        pairs=L.benchmark_pairs("{bench}"),
        prompt=refiner_prompt_input(),
    output:
        manifest=L.refined_manifest("{variant}", "{bench}"),
    log:
        "logs/refiner/infer_{variant}_{bench}.log",
    benchmark:
        "logs/benchmark/refiner/infer_{variant}_{bench}.tsv"
    conda:
        "../../envs/refiner.yaml"
    threads: refiner_threads()
    resources:
        mem_mb=refiner_resource("mem_mb"),
        runtime=refiner_resource("runtime"),
    params:
        **script_params("infer_refiner.py"),
        cfg=refiner_infer_file,
        out_dir=parent_dir,
    shell:
        "python {params.script} --model {input.model} --pairs {input.pairs} "
        "--split test --config-json {params.cfg} --out {params.out_dir} --threads {threads} > {log} 2>&1"


rule evaluate_refiner:
    input:
        pairs=L.benchmark_pairs("{bench}"),
        refined=L.refined_manifest("{variant}", "{bench}"),
    output:
        metrics=L.eval_metrics("{variant}", "{bench}"),
    log:
        "logs/refiner/evaluate_{variant}_{bench}.log",
    benchmark:
        "logs/benchmark/refiner/evaluate_{variant}_{bench}.tsv"
    conda:
        "../../envs/refiner.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=30,
    params:
        **script_params("evaluate_refiner.py"),
        exposure=config["refiner"]["data"]["exposure_ev"],
        weights=evaluation_args,
    shell:
        "python {params.script} --pairs {input.pairs} "
        "--refined {input.refined} --split test --exposure-ev {params.exposure} {params.weights} "
        "--out {output.metrics} > {log} 2>&1"
