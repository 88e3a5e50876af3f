"""Rule withheld_diagnose: the diagnosis of one withheld-effect case (no neural FMU)."""

from pathlib import Path

from hybridfmu_bench.withheld.suite import diagnose_case
from hybridfmu.api.stages import setup_rule_logging

setup_rule_logging(snakemake.log[0])
maneuvers = list(snakemake.params.maneuvers)
diagnose_case(snakemake.input.case, snakemake.input.fmu, dict(zip(maneuvers, snakemake.input.data)),
              dict(zip(maneuvers, snakemake.input.segments)), Path(snakemake.output.json).parent)
