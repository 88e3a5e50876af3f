"""Rule calibrate: fit the FMU's parameters and unmeasured initial states (hybridfmu.calibration)."""

from hybridfmu.api.stages import run_calibration, setup_rule_logging

setup_rule_logging(snakemake.log[0])
run_calibration(
    config=dict(snakemake.params.config),
    fmu_path=snakemake.input.fmu,
    data_paths=dict(zip(snakemake.params.maneuver_names, snakemake.input.data)),
    calibration_path=snakemake.output.calibration,
    figure_path=snakemake.output.figure,
)
