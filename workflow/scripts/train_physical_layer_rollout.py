"""Rule physical_layer_rollout: the hybrid search's untrained state over the validation segments, once."""

import torch

from hybridfmu.api.stages import run_physical_layer_rollout, setup_rule_logging

torch.set_num_threads(max(1, int(snakemake.threads)))
setup_rule_logging(snakemake.log[0])
run_physical_layer_rollout(
    plan_path=snakemake.input.plan,
    train_arrays_path=snakemake.input.train,
    validation_arrays_path=snakemake.input.validation,
    statistics_path=snakemake.input.statistics,
    fmu_path=snakemake.input.fmu,
    calibration_path=snakemake.input.calibration,
    model_config=snakemake.params.model,
    diagnosed_path=snakemake.input.diagnosed,
    rollout_path=snakemake.output.rollout,
)
