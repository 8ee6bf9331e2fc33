# Stage 3, evaluate: E_RMS and E_inf with and without boundary come from each run's
# errors.csv; here they are joined with the published Table 1 (one table per n and
# variant) and stacked over the whole sweep.


rule table1:
    input:
        errors=errors_csvs,
        results=result_jsons,
        # with `ablation: activate: true`, each deviating cell of table1.md names the closest variant
        ablation=lambda wildcards: (
            ["results/report/ablation.csv"]
            if config["ablation"]["activate"] and int(wildcards.n) == PRIMARY_N
            else []
        ),
    output:
        csv=report(
            "results/runs/n{n}/{variant}/table1.csv",
            caption="../report/table1.rst",
            category="Table 1",
            subcategory="n = {n}, {variant}",
            labels={"n": "{n}", "variant": "{variant}", "table": "Table 1 (csv)"},
        ),
        md=report(
            "results/runs/n{n}/{variant}/table1.md",
            caption="../report/table1.rst",
            category="Table 1",
            subcategory="n = {n}, {variant}",
            labels={"n": "{n}", "variant": "{variant}", "table": "Table 1 (Markdown)"},
        ),
    params:
        tolerance=config["report"]["tolerance"],
        options=lambda wildcards: {"n": int(wildcards.n), **variant_options(wildcards.variant)},
        code=CODE_REPORT,
    log:
        "results/logs/table1/n{n}/{variant}.log",
    benchmark:
        "results/benchmarks/table1/n{n}/{variant}.tsv"
    threads: 1
    resources:
        mem_mb=500,
        runtime=5,
    conda:
        "../envs/trivsel.yaml"
    script:
        "../scripts/table1.py"


rule collect_errors:
    input:
        [f"{run_dir(n, v, f)}/errors.csv" for n, v, f in all_runs()],
    output:
        report(
            "results/report/errors_all.csv",
            caption="../report/errors_all.rst",
            category="Sweep",
            labels={"table": "all runs (csv)"},
        ),
    params:
        runs=[variant_columns(n, v) for n, v, f in all_runs()],
        code=CODE_REPORT,
    log:
        "results/logs/collect_errors.log",
    benchmark:
        "results/benchmarks/collect_errors.tsv"
    priority: 2  # erms_figure waits for it (see slice_figure_3d in figures.smk)
    threads: 1
    resources:
        mem_mb=500,
        runtime=5,
    conda:
        "../envs/trivsel.yaml"
    script:
        "../scripts/collect_errors.py"
