"""Rule ingest: one raw log -> the case's signals in their model units on the case's grid (Parquet)."""

from hybridfmu.data.ingest import ingest_to_parquet
from hybridfmu.progress import setup_rule_logging

setup_rule_logging(snakemake.log[0])
ingest_to_parquet(snakemake.input.raw, snakemake.output.data, dict(snakemake.params.config),
                  snakemake.wildcards.maneuver)
