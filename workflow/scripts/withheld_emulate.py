"""Rule withheld_emulate: emulate one truncated maneuver of a withheld-effect case."""

from hybridfmu_bench.withheld.suite import emulate_case
from hybridfmu.api.stages import setup_rule_logging

setup_rule_logging(snakemake.log[0])
emulate_case(snakemake.input.case, snakemake.wildcards.wmaneuver, snakemake.output.mdf, snakemake.output.truth,
             duration_s=snakemake.params.duration_s)
