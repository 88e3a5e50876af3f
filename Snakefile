# Workflow entry point: `snakemake -j2` runs the demo case (config/config.yaml);
# `snakemake -j2 --configfile config/cases/<case>.yaml` runs another case.
# Rules live in workflow/rules/*.smk; all logic lives in the `hybridfmu` package (src/).
from pathlib import Path

# The demo case unless --configfile names another case (whose file then stands alone,
# instead of being merged over the demo's).
if not workflow.config_settings.configfiles:
    configfile: "config/config.yaml"

include: "workflow/rules/common.smk"

# Every rule file appends the files the default target needs to ALL_TARGETS.
rule all:
    input:
        lambda wildcards: ALL_TARGETS,


for _rule_file in sorted(Path(workflow.basedir, "workflow", "rules").glob("*.smk")):
    if _rule_file.name != "common.smk":
        include: str(_rule_file)
