"""Rule withheld_segments: the informative spans of one maneuver of a withheld-effect case."""

from hybridfmu_bench.withheld.suite import segment_case
from hybridfmu.api.stages import setup_rule_logging

setup_rule_logging(snakemake.log[0])
segment_case(snakemake.input.case, snakemake.input.data, snakemake.output.segments, snakemake.output.plot,
             snakemake.wildcards.wmaneuver)
