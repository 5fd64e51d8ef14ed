# The run report: ground-truth counts, evaluation tables, and the cost/quality curves of any
# benchmarks already in results/bench (written by `make bench`).


rule run_report:
    input:
        report_inputs(),
    output:
        report(L.report_index(), category="Report"),
    log:
        "logs/run_report.log",
    benchmark:
        "logs/benchmark/run_report.tsv"
    conda:
        "../../envs/assets.yaml"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    params:
        script=script_path("build_report.py"),
        results=results_root,
    shell:
        "python {params.script} --results {params.results} > {log} 2>&1"
