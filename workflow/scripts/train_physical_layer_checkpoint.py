"""Rule physical_layer_checkpoint: the hybrid's physical layer (ANN at zero) as a candidate of the final choice."""

import torch

from hybridfmu.api.stages import setup_rule_logging, write_physical_layer_checkpoint

torch.set_num_threads(1)
setup_rule_logging(snakemake.log[0])
write_physical_layer_checkpoint(
    plan_path=snakemake.input.plan,
    train_arrays_path=snakemake.input.train,
    validation_arrays_path=snakemake.input.validation,
    statistics_path=snakemake.input.statistics,
    fmu_path=snakemake.input.fmu,
    calibration_path=snakemake.input.calibration,
    model_config=snakemake.params.model,
    diagnosed_path=snakemake.input.diagnosed,
    checkpoint_path=snakemake.output.checkpoint,
)
