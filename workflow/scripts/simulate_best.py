"""Rule simulate_best: the best neural FMU open loop over one whole validation or test maneuver."""

import torch

from hybridfmu.api.stages import case_roles, setup_rule_logging, simulate_best

torch.set_num_threads(1)
setup_rule_logging(snakemake.log[0])
simulate_best(
    best_path=snakemake.input.best,
    fmu_path=snakemake.input.fmu,
    calibration_path=snakemake.input.calibration,
    data_path=snakemake.input.data,
    baseline_path=snakemake.input.baseline,
    trajectory_path=snakemake.output.trajectory,
    learned_path=snakemake.output.learned,
    roles=case_roles(snakemake.params.case),
    maneuvers=snakemake.params.case["maneuvers"],
    maneuver=snakemake.wildcards.maneuver,
    diagnosed_path=snakemake.input.diagnosed,
    hybrid_best_path=snakemake.input.hybrid_best[0] if snakemake.input.hybrid_best else None,
    ceiling_path=snakemake.input.ceiling[0] if snakemake.input.ceiling else None,
    window_length_s=snakemake.params.window_length_s,
)
