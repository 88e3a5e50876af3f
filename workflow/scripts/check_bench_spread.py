"""Rule check_bench_spread: the realised max load and max speed of maneuvers of different roles differ by >= 10 %."""
from hybridfmu_bench.emulate import summarize_bench
from hybridfmu.api.stages import setup_rule_logging

setup_rule_logging(snakemake.log[0])
summarize_bench(dict(zip(snakemake.params.maneuvers, snakemake.input.truth)), snakemake.output.summary,
                roles=dict(snakemake.params.roles))
