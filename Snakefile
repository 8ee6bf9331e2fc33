# trivsel: reproduction of Hamann & Chen (1994), Table 1 and Figs. 4-6.
#
#   snakemake -c all                                   the paper (config.yaml)
#   snakemake -c all --configfile config/resolution.yaml   a sweep
#   snakemake --report report.html                     HTML report after a run
#
# Stages (workflow/rules/): data -> reduce -> evaluate -> figures -> report.
# Results layout: results/README.md.

from snakemake.utils import min_version, validate

min_version("9.0")


configfile: "config.yaml"


validate(config, "workflow/schemas/config.schema.yaml")


report: "workflow/report/workflow.rst"


include: "workflow/rules/common.smk"
include: "workflow/rules/data.smk"
include: "workflow/rules/reduce.smk"
include: "workflow/rules/evaluate.smk"
include: "workflow/rules/figures.smk"
include: "workflow/rules/report.smk"


# Jobs that only collect or copy files run on the submitting host, not as cluster jobs.
localrules:
    all,
    publish,


rule all:
    input:
        all_targets(),
    default_target: True
