# Stage 4, figures: Figs. 4-6 of the paper for every function (matplotlib mid-plane
# slices and a pyvista off-screen 3-D rendering) and E_RMS against the fraction.


rule slice_figure:
    input:
        data="results/data/f{function}_n{n}.npz",
        errors="results/runs/n{n}/{variant}/f{function}/errors.csv",
        meshes=expand(
            "results/runs/n{{n}}/{{variant}}/f{{function}}/mesh_{fraction}.vtu",
            fraction=FRACTION_LABELS,
        ),
    output:
        report(
            "results/runs/n{n}/{variant}/figures/slices_f{function}.png",
            caption="../report/slices.rst",
            category="Figures 4-6 (slices)",
            subcategory="n = {n}, {variant}",
            labels={"function": "{function}", "n": "{n}", "figure": "mid-plane slices"},
        ),
    params:
        fractions=FRACTIONS,
        code=CODE_FIGURES,
    log:
        "results/logs/slice_figure/n{n}/{variant}/f{function}.log",
    benchmark:
        "results/benchmarks/slice_figure/n{n}/{variant}/f{function}.tsv"
    threads: 1
    resources:
        mem_mb=figure_mem_mb,
        runtime=10,
    conda:
        "../envs/trivsel.yaml"
    script:
        "../scripts/slice_figure.py"


rule slice_figure_3d:
    input:
        data="results/data/f{function}_n{n}.npz",
        errors="results/runs/n{n}/{variant}/f{function}/errors.csv",
        meshes=expand(
            "results/runs/n{{n}}/{{variant}}/f{{function}}/mesh_{fraction}.vtu",
            fraction=FRACTION_LABELS,
        ),
    output:
        report(
            "results/runs/n{n}/{variant}/figures/slices3d_f{function}.png",
            caption="../report/slices3d.rst",
            category="Figures 4-6 (3-D)",
            subcategory="n = {n}, {variant}",
            labels={"function": "{function}", "n": "{n}", "figure": "3-D slices"},
        ),
    params:
        fractions=FRACTIONS,
        code=CODE_FIGURES,
    log:
        "results/logs/slice_figure_3d/n{n}/{variant}/f{function}.log",
    benchmark:
        "results/benchmarks/slice_figure_3d/n{n}/{variant}/f{function}.tsv"
    threads: 1
    resources:
        mem_mb=figure_mem_mb,
        runtime=10,
    conda:
        "../envs/trivsel.yaml"
    script:
        "../scripts/slice_figure_3d.py"


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
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    conda:
        "../envs/trivsel.yaml"
    script:
        "../scripts/erms_figure.py"
