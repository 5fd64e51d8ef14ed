# The run report (lightcrafter.report): Tables 1 and 2, clips, reconstruction errors, leave-out counts,
# per-stage cost from logs/benchmark and the projected cost of config/paper.yaml, benchmark curves
# (results/bench, written by `make bench`), long-form relighting and scene edits when present.


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
        "../../envs/refiner.yaml"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=15,
    params:
        **script_params("build_report.py"),
        results=results_root,
        cfg=params_file(
            {
                k: config[k]
                for k in ("seed", "scenes", "render", "proxy", "real", "recon")
            }
        ),
        paper=paper_config_file,
    shell:
        "python {params.script} --results {params.results} --logs logs --config-json {params.cfg} "
        "--project {params.paper} > {log} 2>&1"
