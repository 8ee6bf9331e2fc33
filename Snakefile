# trivsel: reproduction of Hamann & Chen (1994), Table 1 and Figs. 4-6.
#
#   snakemake -c all                                   the paper (config.yaml)
#   snakemake -c all --configfile config/resolution.yaml   a sweep
#   snakemake --report report.html                     HTML report after a run
#
# Stages (workflow/rules/): data -> reduce -> evaluate -> figures -> report.
# The reduction options (config `reduce: options:`) are trivsel.Options fields, each a list:
# the variants are their combinations, results/runs/n{n}/{variant}/ (docs/workflow.md).
# Optional stage methods (config/methods.yaml): every method at matched vertex counts.
# Optional stage ablation (config/ablation.yaml): the open choices against Table 1.
# Optional stage scale (config/scale.yaml): time and memory against points, trivsel vs VTK.
# Optional stage realdata (config/realdata.yaml): trivsel vs VTK on real volumes.
# Results layout: results/README.md.

from snakemake.utils import min_version, validate

min_version("9.0")


configfile: "config.yaml"


# Every section, and `reduce: options:` through a $ref to the generated
# workflow/schemas/options.schema.json (python -m trivsel.options); common.smk then builds
# the trivsel.Options of every variant, so a bad value stops the workflow before any job.
validate(config, "workflow/schemas/config.schema.yaml")


report: "workflow/report/workflow.rst"


include: "workflow/rules/common.smk"
include: "workflow/rules/data.smk"
include: "workflow/rules/reduce.smk"
include: "workflow/rules/evaluate.smk"
include: "workflow/rules/figures.smk"
include: "workflow/rules/report.smk"
include: "workflow/rules/methods.smk"
include: "workflow/rules/ablation.smk"
include: "workflow/rules/scale.smk"
include: "workflow/rules/realdata.smk"


# Jobs that only collect or copy files run on the submitting host, not as cluster jobs.
localrules:
    all,
    publish,
    methods_table,
    ablation_report,
    scale_table,
    scale_figure,
    realdata_table,
    realdata_figure,


rule all:
    input:
        all_targets(),
        ABLATION_TARGETS,
        SCALE_TARGETS,
        REALDATA_TARGETS,
    default_target: True
