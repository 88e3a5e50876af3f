"""Rule score_finalist: one candidate of a search's final choice open loop over whole maneuvers
-> {search}/finalists/{candidate}.json."""

import torch

from hybridfmu.api.stages import case_roles, score_candidate, setup_rule_logging

torch.set_num_threads(1)
setup_rule_logging(snakemake.log[0])
score_candidate(
    candidate=snakemake.wildcards.candidate,
    plan_path=snakemake.input.plan,
    selection_paths=list(snakemake.input.selections),
    top=snakemake.params.top,
    maneuver_paths={name: {"data": data, "baseline": baseline} for name, data, baseline in
                    zip(snakemake.params.maneuvers, snakemake.input.data, snakemake.input.baselines)},
    fmu_path=snakemake.input.fmu,
    calibration_path=snakemake.input.calibration,
    roles=case_roles(snakemake.params.case),
    maneuvers_config=snakemake.params.case["maneuvers"],
    score_path=snakemake.output.score,
    diagnosed_path=snakemake.input.diagnosed[0] if snakemake.input.diagnosed else None,
    physical_layer_path=snakemake.input.physical_layer[0] if snakemake.input.physical_layer else None,
)
