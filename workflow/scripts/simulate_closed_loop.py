"""Rule simulate_closed_loop: one model driven by the case's controller over every evaluated maneuver."""

import torch

from hybridfmu.api.stages import (case_roles, closed_loop_model, closed_loop_settings, setup_rule_logging,
                                  write_closed_loop)

torch.set_num_threads(1)
setup_rule_logging(snakemake.log[0])
roles = case_roles(snakemake.params.case)
controller_config = dict(snakemake.params.controller_config)
model, start = closed_loop_model(
    snakemake.wildcards.model,
    best_path=snakemake.input.best,
    fmu_path=snakemake.input.fmu,
    calibration_path=snakemake.input.calibration,
    roles=roles,
    maneuvers=snakemake.params.case["maneuvers"],
    diagnosed_path=snakemake.input.diagnosed[0] if snakemake.input.diagnosed else None,
    hybrid_best_path=snakemake.input.hybrid_best[0] if snakemake.input.hybrid_best else None,
    physical_layer_path=snakemake.input.physical_layer[0] if snakemake.input.physical_layer else None,
)
write_closed_loop(snakemake.wildcards.model, model, start,
                  dict(zip(snakemake.params.maneuvers, snakemake.input.data)),
                  dict(zip(snakemake.params.maneuvers, snakemake.output.trajectories)),
                  roles, closed_loop_settings(controller_config, roles), controller_config)
