"""Rule simulate_ceiling: the bench's true plant open loop over one evaluated maneuver (the ceiling)."""
from hybridfmu_bench.ceiling import write_ceiling
from hybridfmu.api.stages import case_roles, setup_rule_logging

setup_rule_logging(snakemake.log[0])
write_ceiling(dict(snakemake.params.config), snakemake.wildcards.maneuver, snakemake.input.raw, snakemake.input.data,
              case_roles(snakemake.params.case), snakemake.output.trajectory, snakemake.params.window_length_s)
