"""Rule choose_grid: the grid rate and the FMU inputs' conventions between samples the config leaves out, from
the train and validation maneuvers' logs."""

from hybridfmu.api.stages import choose_grid, setup_rule_logging

setup_rule_logging(snakemake.log[0])
config = dict(snakemake.params.config)
choose_grid({name: entry["raw"] for name, entry in config["maneuvers"].items()}, config, snakemake.output.grid)
