"""Rule export: one trained model as an FMI 2.0 Co-Simulation FMU, replayed with FMPy against the evaluation."""

import torch

from hybridfmu.api.stages import case_roles, export_model, setup_rule_logging

torch.set_num_threads(1)
setup_rule_logging(snakemake.log[0])
export_model(
    model=snakemake.wildcards.model,
    case=snakemake.params.case,
    config=snakemake.config,  # for the provenance's digest only (not a param: a change of it reruns nothing)
    best_path=snakemake.input.best[0] if snakemake.input.best else None,
    fmu_path=snakemake.input.fmu,
    calibration_path=snakemake.input.calibration,
    check_maneuvers=snakemake.params.check_maneuvers,
    data_paths=list(snakemake.input.data),
    trajectory_paths=list(snakemake.input.trajectories),
    roles=case_roles(snakemake.params.case_sections),
    fmu_out=snakemake.output.fmu,
    record_out=snakemake.output.record,
    run_path=snakemake.input.run,
    diagnosed_path=snakemake.input.diagnosed[0] if snakemake.input.diagnosed else None,
    grid_path=snakemake.input.grid[0] if snakemake.input.grid else None,
    diagnosis_path=snakemake.input.diagnosis[0] if snakemake.input.diagnosis else None,
)
