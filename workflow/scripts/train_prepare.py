"""Rule hpo_prepare: arrays of the train and validation maneuvers, and the training data statistics."""

from hybridfmu.api.stages import case_roles, prepare_training_data, setup_rule_logging

setup_rule_logging(snakemake.log[0])
prepare_training_data(
    fmu_path=snakemake.input.fmu,
    calibration_path=snakemake.input.calibration,
    roles=case_roles(snakemake.params.case),
    maneuvers=snakemake.params.maneuvers,
    maneuvers_config=snakemake.params.case["maneuvers"],
    data_paths={"train": snakemake.input.train_data, "validation": snakemake.input.validation_data},
    segments_paths={"train": snakemake.input.train_segments, "validation": snakemake.input.validation_segments},
    baseline_paths=snakemake.params.baselines,
    array_paths={"train": snakemake.output.train, "validation": snakemake.output.validation},
    statistics_path=snakemake.output.statistics,
)
