"""Rule ingest: one raw log -> the case's signals in their model units on the case's grid (Parquet)."""

from hybridfmu.api.stages import chosen_conventions, grid_rate_hz, ingest_to_parquet, setup_rule_logging

setup_rule_logging(snakemake.log[0])
config = dict(snakemake.params.config)
grid = snakemake.input.grid[0] if snakemake.input.grid else None
ingest_to_parquet(snakemake.input.raw, snakemake.output.data, config, snakemake.wildcards.maneuver,
                  grid_rate_hz(config, grid), chosen_conventions(grid))
