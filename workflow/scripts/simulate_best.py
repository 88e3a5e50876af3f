"""Rule simulate_best: the best neural FMU open loop over one whole validation or test maneuver."""

import torch

from hybridfmu.evaluation.evaluate import simulate_best
from hybridfmu.progress import setup_rule_logging

torch.set_num_threads(1)
setup_rule_logging(snakemake.log[0])
simulate_best(
    best_path=snakemake.input.best,
    fmu_path=snakemake.input.fmu,
    data_path=snakemake.input.data,
    baseline_path=snakemake.input.baseline,
    trajectory_path=snakemake.output.trajectory,
    learned_path=snakemake.output.learned,
    signals_config=snakemake.params.signals,
    fmu_parameters=snakemake.params.fmu_parameters,
    maneuver=snakemake.wildcards.maneuver,
)
