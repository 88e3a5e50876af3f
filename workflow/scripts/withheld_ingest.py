"""Rule withheld_ingest: ingest one raw log of a withheld-effect case."""

from hybridfmu_bench.withheld.suite import ingest_case
from hybridfmu.api.stages import setup_rule_logging

setup_rule_logging(snakemake.log[0])
ingest_case(snakemake.input.case, snakemake.input.raw, snakemake.output.data)
