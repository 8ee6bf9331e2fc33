# Stage 4, figures: Figs. 4-6 of the paper for every function (matplotlib mid-plane
# slices and a pyvista off-screen 3-D rendering, one job each per n and variant) and E_RMS
# against the fraction.


rule slice_figure:
    """One job per (n, variant) draws the figure of every function: the imports and the
    renderer start once instead of once per function."""
    input:
        data=expand("results/data/f{function}_n{{n}}.npz", function=FUNCTIONS),
        errors=expand("results/runs/n{{n}}/{{variant}}/f{function}/errors.csv", function=FUNCTIONS),
        meshes=expand(
            "results/runs/n{{n}}/{{variant}}/f{function}/mesh_{fraction}.vtu",
            function=FUNCTIONS,
            fraction=FRACTION_LABELS,
        ),
    output:
        [
            report(
                f"results/runs/n{{n}}/{{variant}}/figures/slices_f{f}.png",
                caption="../report/slices.rst",
                category="Figures 4-6 (slices)",
                subcategory="n = {n}, {variant}",
                labels={"function": str(f), "n": "{n}", "figure": "mid-plane slices"},
            )
            for f in FUNCTIONS
        ],
    params:
        draw="slice_figure",
        functions=FUNCTIONS,
        fractions=FRACTIONS,
        code=CODE_FIGURES,
    log:
        "results/logs/slice_figure/n{n}/{variant}.log",
    benchmark:
        "results/benchmarks/slice_figure/n{n}/{variant}.tsv"
    # the jobs after the reductions, longest first (see slice_figure_3d)
    priority: 1
    threads: 1
    resources:
        mem_mb=figure_mem_mb,
        runtime=10,
    conda:
        "../envs/trivsel.yaml"
    script:
        "../scripts/slice_figures.py"


rule slice_figure_3d:
    """One job per (n, variant) draws the figure of every function: the imports and the
    renderer start once instead of once per function."""
    input:
        data=expand("results/data/f{function}_n{{n}}.npz", function=FUNCTIONS),
        errors=expand("results/runs/n{{n}}/{{variant}}/f{function}/errors.csv", function=FUNCTIONS),
        meshes=expand(
            "results/runs/n{{n}}/{{variant}}/f{function}/mesh_{fraction}.vtu",
            function=FUNCTIONS,
            fraction=FRACTION_LABELS,
        ),
    output:
        [
            report(
                f"results/runs/n{{n}}/{{variant}}/figures/slices3d_f{f}.png",
                caption="../report/slices3d.rst",
                category="Figures 4-6 (3-D)",
                subcategory="n = {n}, {variant}",
                labels={"function": str(f), "n": "{n}", "figure": "3-D slices"},
            )
            for f in FUNCTIONS
        ],
    params:
        draw="slice_figure_3d",
        functions=FUNCTIONS,
        fractions=FRACTIONS,
        code=CODE_FIGURES,
    log:
        "results/logs/slice_figure_3d/n{n}/{variant}.log",
    benchmark:
        "results/benchmarks/slice_figure_3d/n{n}/{variant}.tsv"
    # the jobs after the reductions, longest first: this one and the chain collect_errors ->
    # erms_figure, then the 2-D figures, then the tables; on 2 cores the run then ends with
    # the two cores about equally busy instead of with this job alone
    priority: 2
    threads: 1
    resources:
        mem_mb=figure_mem_mb,
        runtime=10,
    conda:
        "../envs/trivsel.yaml"
    script:
        "../scripts/slice_figures.py"


rule erms_figure:
    input:
        "results/report/errors_all.csv",
    output:
        report(
            "results/report/erms_vs_fraction.png",
            caption="../report/erms.rst",
            category="Sweep",
            labels={"figure": "E_RMS vs fraction"},
        ),
    params:
        code=CODE_FIGURES,
    log:
        "results/logs/erms_figure.log",
    benchmark:
        "results/benchmarks/erms_figure.tsv"
    priority: 2  # see slice_figure_3d
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    conda:
        "../envs/trivsel.yaml"
    script:
        "../scripts/erms_figure.py"
