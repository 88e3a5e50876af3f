"""Rule hybrid_time_offset: each input group's time offset with the hybrid's physical layer (its delays' start)."""

from hybridfmu.api.stages import case_roles, run_hybrid_time_offset, setup_rule_logging

setup_rule_logging(snakemake.log[0])
run_hybrid_time_offset(
    fmu_path=snakemake.input.fmu,
    calibration_path=snakemake.input.calibration,
    diagnosed_path=snakemake.input.diagnosed,
    data_path=snakemake.input.data,
    summary_path=snakemake.output.summary,
    options=snakemake.params.options,
    roles=case_roles(snakemake.params.case),
    maneuvers=snakemake.params.case["maneuvers"],
    maneuver=snakemake.params.maneuver,
    model_config=snakemake.params.model,
)
