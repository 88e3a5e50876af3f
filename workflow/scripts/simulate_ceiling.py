"""Rule simulate_ceiling: the bench's true plant open loop over one evaluated maneuver (the ceiling)."""
from hybridfmu_bench.ceiling import write_ceiling
from hybridfmu.data.roles import case_roles
from hybridfmu.progress import setup_rule_logging

setup_rule_logging(snakemake.log[0])
write_ceiling(dict(snakemake.params.config), snakemake.wildcards.maneuver, snakemake.input.raw, snakemake.input.data,
              case_roles(snakemake.params.case), snakemake.output.trajectory, snakemake.params.window_length_s)
