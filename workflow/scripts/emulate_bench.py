"""Rule emulate_bench: emulate one maneuver on the test bench (MDF4 log + ground truth)."""
from hybridfmu_bench.emulate import emulate_bench
from hybridfmu.api.stages import setup_rule_logging

setup_rule_logging(snakemake.log[0])
emulate_bench(dict(snakemake.params.config), snakemake.wildcards.maneuver, mdf_path=snakemake.output.mdf,
              truth_path=snakemake.output.truth, roles=dict(snakemake.params.roles))
