# Optional stage, realdata: trivsel's methods against VTK's tetrahedral quadric decimation on
# real volumes shipped inside the nilearn and dipy wheels and two synthetic ones, like for like.
# Off by default (`realdata: activate: false`); on with
#   snakemake -c all --configfile config/realdata.yaml     (needs pip install -e '.[realdata]')
# One job per volume (realdata_run) measures the table's rows (trivsel.study.realdata.measure)
# and the curves of E_RMS against the vertex count (trivsel.study.realdata.curves);
# realdata_table stacks the rows into the ratio table with the targets checked, and
# realdata_figure draws each volume's curves.  The work is in the package; these rules only
# call it.

REALDATA = config["realdata"]
REALDATA_VOLUMES = list(REALDATA["volumes"])
REALDATA_TARGETS = (
    ["results/report/realdata.csv", "results/report/realdata.md"]
    + [f"results/report/figures/realdata_{v}.png" for v in REALDATA_VOLUMES]
    if REALDATA["activate"]
    else []
)


rule realdata_run:
    output:
        rows="results/realdata/{volume}.csv",
        curves="results/realdata/{volume}_curves.csv",
    params:
        fractions=REALDATA["fractions"],
        curve_fractions=REALDATA["curve_fractions"],
        methods=REALDATA["methods"],
        repeats=REALDATA["repeats"],
        quick=REALDATA["quick"],
        code=CODE_REALDATA,
    wildcard_constraints:
        volume="|".join(REALDATA_VOLUMES),
    log:
        "results/logs/realdata_run/{volume}.log",
    benchmark:
        "results/benchmarks/realdata_run/{volume}.tsv"
    threads: 1
    resources:
        # a 48^3 volume (110 592 voxels): VTK's input meshes and the sparse refits
        mem_mb=lambda wildcards, attempt: (1000 if REALDATA["quick"] else 4000) * attempt,
        # minutes: VTK's screen of splits and weights at every fraction of the rows and curves
        runtime=lambda wildcards, attempt: (
            5 if REALDATA["quick"] else 10 + 10 * len(REALDATA["fractions"] + REALDATA["curve_fractions"])
        )
        * attempt,
    conda:
        "../envs/trivsel.yaml"
    script:
        "../scripts/realdata_run.py"


rule realdata_table:
    input:
        expand("results/realdata/{volume}.csv", volume=REALDATA_VOLUMES),
    output:
        csv=report(
            "results/report/realdata.csv",
            caption="../report/realdata.rst",
            category="Real volumes",
            labels={"table": "ratios and targets per row and method (csv)"},
        ),
        md=report(
            "results/report/realdata.md",
            caption="../report/realdata.rst",
            category="Real volumes",
            labels={"table": "targets, ratios and details (Markdown)"},
        ),
    params:
        methods=REALDATA["methods"],
        figures={v: f"figures/realdata_{v}.png" for v in REALDATA_VOLUMES},
        code=CODE_REALDATA_REPORT,
    log:
        "results/logs/realdata_table.log",
    benchmark:
        "results/benchmarks/realdata_table.tsv"
    threads: 1
    resources:
        mem_mb=500,
        runtime=5,
    conda:
        "../envs/trivsel.yaml"
    script:
        "../scripts/realdata_table.py"


rule realdata_figure:
    input:
        "results/realdata/{volume}_curves.csv",
    output:
        report(
            "results/report/figures/realdata_{volume}.png",
            caption="../report/realdata_figure.rst",
            category="Real volumes",
            labels={"volume": "{volume}", "figure": "E_RMS vs vertex count"},
        ),
    params:
        code=CODE_REALDATA_REPORT,
    wildcard_constraints:
        volume="|".join(REALDATA_VOLUMES),
    log:
        "results/logs/realdata_figure/{volume}.log",
    benchmark:
        "results/benchmarks/realdata_figure/{volume}.tsv"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    conda:
        "../envs/trivsel.yaml"
    script:
        "../scripts/realdata_figure.py"
