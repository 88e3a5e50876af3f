"""Rule choose_grid: the case's grid rate from every maneuver's log, where config.ingest.rate_hz leaves it out."""

from hybridfmu.data.ingest import choose_grid
from hybridfmu.progress import setup_rule_logging

setup_rule_logging(snakemake.log[0])
config = dict(snakemake.params.config)
choose_grid({name: entry["raw"] for name, entry in config["maneuvers"].items()}, config, snakemake.output.grid)
