"""Rule robustness_summary: the case's test figures pooled over every (seed, maneuver)."""
from hybridfmu.api.stages import seed_job_counts, seed_wall_times, setup_rule_logging, write_summary

setup_rule_logging(snakemake.log[0])
paths = {snakemake.params.own_seed: snakemake.input.own,
         **dict(zip(snakemake.params.other_seeds, snakemake.input.others))}
write_summary(snakemake.params.case, paths, snakemake.output.summary, snakemake.output.markdown,
              seed_wall_times(snakemake.input.benchmarks, snakemake.params.other_seeds),
              reference=snakemake.params.reference,
              jobs=seed_job_counts(snakemake.params.run_logs, snakemake.params.other_seeds))
