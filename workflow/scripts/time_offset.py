"""Rule time_offset: the FMU against the measured speed on a short window (paper Fig. 6)."""

from hybridfmu.evaluation.offset import run_time_offset
from hybridfmu.progress import setup_rule_logging

setup_rule_logging(snakemake.log[0])
run_time_offset(
    fmu_path=snakemake.input.fmu,
    data_path=snakemake.input.data,
    window_path=snakemake.output.window,
    summary_path=snakemake.output.summary,
    options=snakemake.params.options,
    fmu_parameters=snakemake.params.fmu_parameters,
    signals_config=snakemake.params.signals,
    maneuver=snakemake.params.maneuver,
)
