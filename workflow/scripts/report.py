"""Rule report: report.md (improvement factors beside the paper's, figures, hyperparameters, learned dt)."""

from hybridfmu.api.stages import case_roles, setup_rule_logging, write_report

setup_rule_logging(snakemake.log[0])
write_report(
    report_path=snakemake.output[0],
    case=snakemake.params.case,
    metrics_paths=list(snakemake.input.metrics),
    best_path=snakemake.input.best,
    run_path=snakemake.input.run,
    time_offset_summary_path=snakemake.input.time_offset_summary,
    figure_paths=dict(zip(snakemake.params.figure_names, snakemake.input.figures)),
    truth_paths=list(snakemake.input.truth),
    roles=case_roles(snakemake.params.case_sections),
    reference=snakemake.params.reference,
    hybrid_time_offset_path=next(iter(snakemake.input.hybrid_time_offset), None),  # a list: empty or the file
    chosen_paths=list(snakemake.input.chosen),
)
