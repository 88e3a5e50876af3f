"""Rule simulate_baseline: the calibrated FMU open loop over one whole maneuver."""

from hybridfmu.api.stages import case_roles, run_baseline, setup_rule_logging

setup_rule_logging(snakemake.log[0])
run_baseline(
    fmu_path=snakemake.input.fmu,
    calibration_path=snakemake.input.calibration,
    data_path=snakemake.input.data,
    trajectory_path=snakemake.output.trajectory,
    metrics_path=snakemake.output.metrics,
    roles=case_roles(snakemake.params.case),
    maneuvers=snakemake.params.case["maneuvers"],
    maneuver=snakemake.wildcards.maneuver,
)
