"""Rule simulate_baseline: the FMU open loop over one whole maneuver."""

from hybridfmu.evaluation.baseline import run_baseline
from hybridfmu.progress import setup_rule_logging

setup_rule_logging(snakemake.log[0])
run_baseline(
    fmu_path=snakemake.input.fmu,
    data_path=snakemake.input.data,
    trajectory_path=snakemake.output.trajectory,
    metrics_path=snakemake.output.metrics,
    fmu_parameters=snakemake.params.fmu_parameters,
    signals_config=snakemake.params.signals,
    maneuver=snakemake.wildcards.maneuver,
)
