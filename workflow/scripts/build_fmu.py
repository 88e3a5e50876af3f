"""Rule build_fmu: compile the C sources of the FMU named by the {model} wildcard and package it."""

from hybridfmu.api.stages import build_fmu, setup_rule_logging

setup_rule_logging(snakemake.log[0])
build_fmu(snakemake.wildcards.model, snakemake.output[0])
