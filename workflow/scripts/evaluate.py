"""Rule evaluate: the best neural FMU and the FMU open loop over the whole validation and test maneuvers."""

import torch

from hybridfmu.evaluation.evaluate import run_evaluation
from hybridfmu.progress import setup_rule_logging

torch.set_num_threads(1)
setup_rule_logging(snakemake.log[0])
run_evaluation(
    best_path=snakemake.input.best,
    fmu_path=snakemake.input.fmu,
    data_paths=list(snakemake.input.data),
    baseline_paths=list(snakemake.input.baseline),
    maneuver_roles=snakemake.params.maneuvers,
    metrics_paths=list(snakemake.output.metrics),
    trajectory_paths=list(snakemake.output.trajectories),
    run_path=snakemake.output.run,
    zoom_settings=snakemake.params.zoom,
    signals_config=snakemake.params.signals,
    mlflow_config=snakemake.params.mlflow,
    results_dir=snakemake.params.results_dir,
    case=snakemake.params.case,
)
