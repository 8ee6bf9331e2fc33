# Optional stage, ablation: every open choice of the paper, alone and in
# combinations, against Table 1.  Off by default (`ablation: activate: false`, so the paper
# run stays fast); on with   snakemake -c all --configfile config/ablation.yaml
# One job per variant runs all functions at the primary n (trivsel.study.ablation.run_variant);
# ablation_report stacks them into results/report/ablation.csv and ablation.md.
# Helpers live in the package (trivsel.study.ablation), so this file has rules only.

from snakemake.exceptions import WorkflowError

import trivsel.study.ablation as ablation_pkg

# The variant names are checked whether the stage is on or not, like the schema's keys, so a
# bad name stops the workflow when it loads with one line naming the key and the entry
# (trivsel.study.ablation raises ValueError).
try:
    _ABLATION_NAMES = ablation_pkg.variant_names(config["ablation"]["variants"])
except ValueError as exc:
    raise WorkflowError(f"config ablation: variants: {exc}") from None
ABLATION_VARIANTS = _ABLATION_NAMES if config["ablation"]["activate"] else []
ABLATION_TARGETS = (
    ["results/report/ablation.csv", "results/report/ablation.md"]
    if config["ablation"]["activate"]
    else []
)


rule ablation_run:
    output:
        "results/ablation/n{n}/{ablation_variant}.csv",
    params:
        functions=FUNCTIONS,
        fractions=FRACTIONS,
        code=CODE_ABLATION,
    wildcard_constraints:
        ablation_variant="|".join(re.escape(v) for v in ABLATION_VARIANTS) or "default",
    log:
        "results/logs/ablation_run/n{n}/{ablation_variant}.log",
    benchmark:
        "results/benchmarks/ablation_run/n{n}/{ablation_variant}.tsv"
    threads: 1
    resources:
        mem_mb=reduce_mem_mb,
        runtime=lambda wildcards, attempt: reduce_runtime(wildcards, attempt) * len(FUNCTIONS),
    conda:
        "../envs/trivsel.yaml"
    script:
        "../scripts/ablation_run.py"


rule ablation_report:
    input:
        expand("results/ablation/n{n}/{v}.csv", n=PRIMARY_N, v=ABLATION_VARIANTS),
    output:
        csv=report(
            "results/report/ablation.csv",
            caption="../report/ablation.rst",
            category="Ablation",
            labels={"table": "ablation (csv, one row per variant, function, fraction)"},
        ),
        md=report(
            "results/report/ablation.md",
            caption="../report/ablation.rst",
            category="Ablation",
            labels={"table": "ablation summary (Markdown)"},
        ),
        summary="results/report/ablation_summary.csv",
        closest="results/report/ablation_closest.csv",
    params:
        tolerance=config["report"]["tolerance"],
        code=CODE_ABLATION_REPORT,
    log:
        "results/logs/ablation_report.log",
    benchmark:
        "results/benchmarks/ablation_report.tsv"
    threads: 1
    resources:
        mem_mb=500,
        runtime=5,
    conda:
        "../envs/trivsel.yaml"
    script:
        "../scripts/ablation_report.py"
