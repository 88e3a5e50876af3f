"""Rule summary: the run's measured test figures as the documentation quotes them."""

from hybridfmu.api.stages import case_roles, setup_rule_logging, write_case_summary

setup_rule_logging(snakemake.log[0])
roles = case_roles(snakemake.params.case_sections)
write_case_summary(snakemake.output.summary, snakemake.params.case, snakemake.input.test_metrics,
                   snakemake.input.get("diagnosis"), {name: s.unit for name, s in roles.signals.items()},
                   best_path=snakemake.input.best, time_offset_path=snakemake.input.time_offset,
                   truth_paths=list(snakemake.input.truth), roles=roles,
                   hybrid_time_offset_path=next(iter(snakemake.input.hybrid_time_offset), None))
