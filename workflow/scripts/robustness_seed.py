"""Rule robustness_seed: the whole case rerun with one more master seed (a nested Snakemake run)."""
from hybridfmu.api.stages import run_seed, setup_rule_logging

setup_rule_logging(snakemake.log[0])
run_seed(dict(snakemake.params.config), int(snakemake.wildcards.seed), snakemake.params.config_path,
         snakemake.params.snakefile, snakemake.threads, snakemake.output.metrics, snakemake.params.run_log)
