# Pair manifests (lightcrafter.datasets): a training set per dataset variant of the registry
# (VARIANTS: full, no_real, no_synthetic, clean_buffers) and the held-out benchmarks every variant is
# scored on (synthetic: test scenes with Phi proxies; real: test real clips, relit to the fitted light).


rule dataset:
    input:
        variant_inputs,
    output:
        pairs=L.pairs("{variant}"),
    log:
        "logs/dataset/{variant}.log",
    benchmark:
        "logs/benchmark/dataset/{variant}.tsv"
    priority: variant_priority
    conda:
        "../../envs/refiner.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,
    params:
        **script_params("build_dataset.py"),
        specs=variant_specs_file,
    shell:
        "python {params.script} --variant {wildcards.variant} --specs {params.specs} "
        "--output {output.pairs} > {log} 2>&1"


rule benchmark_pairs:
    input:
        benchmark_inputs,
    output:
        pairs=L.benchmark_pairs("{bench}"),
    log:
        "logs/dataset/benchmark_{bench}.log",
    benchmark:
        "logs/benchmark/dataset/benchmark_{bench}.tsv"
    conda:
        "../../envs/refiner.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,
    params:
        **script_params("build_dataset.py"),
        specs=benchmark_specs_file,
    shell:
        "python {params.script} --benchmark {wildcards.bench} --specs {params.specs} "
        "--output {output.pairs} > {log} 2>&1"
