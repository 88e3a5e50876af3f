"""Rule time_offset: the calibrated FMU against the measured targets on a short window (paper Fig. 6)."""

from hybridfmu.api.stages import case_roles, run_time_offset, setup_rule_logging

setup_rule_logging(snakemake.log[0])
run_time_offset(
    fmu_path=snakemake.input.fmu,
    calibration_path=snakemake.input.calibration,
    data_path=snakemake.input.data,
    window_path=snakemake.output.window,
    summary_path=snakemake.output.summary,
    options=snakemake.params.options,
    roles=case_roles(snakemake.params.case),
    maneuvers=snakemake.params.case["maneuvers"],
    maneuver=snakemake.params.maneuver,
    delay_config=snakemake.params.delay,
)
