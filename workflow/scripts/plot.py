"""Rule plot: the paper's figures, training curves and the Hyperband overview, from saved results."""

from hybridfmu.api.stages import case_roles, draw_all, setup_rule_logging

setup_rule_logging(snakemake.log[0])
draw_all(
    figure_paths=dict(snakemake.output.items()),
    metrics_paths=list(snakemake.input.metrics),
    trajectory_paths=list(snakemake.input.trajectories),
    time_offset_path=snakemake.input.time_offset,
    time_offset_summary_path=snakemake.input.time_offset_summary,
    best_path=snakemake.input.best,
    hpo_dir=snakemake.params.hpo_dir,
    maneuver_roles=snakemake.params.maneuvers,
    plot_options=snakemake.params.plot,
    roles=case_roles(snakemake.params.case),
)
