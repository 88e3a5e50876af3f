"""Rule evaluate: errors of the FMU and the best neural FMU (whole trajectories, zoomed intervals), MLflow run."""

from hybridfmu.api.stages import run_evaluation, setup_rule_logging

setup_rule_logging(snakemake.log[0])
run_evaluation(
    best_path=snakemake.input.best,
    trajectory_paths=list(snakemake.input.trajectories),
    learned_paths=list(snakemake.input.learned),
    maneuver_roles=snakemake.params.maneuvers,
    metrics_paths=list(snakemake.output.metrics),
    run_path=snakemake.output.run,
    zoom_settings=snakemake.params.zoom,
    tolerance=snakemake.params.tolerance,
    closed_loop_paths=list(snakemake.input.closed_loop),
    closed_loop_models=list(snakemake.params.closed_loop_models),
    mlflow_config=snakemake.params.mlflow,
    results_dir=snakemake.params.results_dir,
    case=snakemake.params.case,
)
