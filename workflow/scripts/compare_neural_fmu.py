"""Rule compare_neural_fmu: the search's best neural FMU beside the diagnosis (neural_fmu.json, neural_fmu.md)."""

from pathlib import Path

import torch

from hybridfmu.api.stages import compare_neural_fmu, setup_rule_logging

torch.set_num_threads(1)
setup_rule_logging(snakemake.log[0])
maneuvers = list(snakemake.params.maneuvers)
compare_neural_fmu(
    config=dict(snakemake.params.config),
    fmu_path=snakemake.input.fmu,
    data_paths=dict(zip(maneuvers, snakemake.input.data)),
    segments_paths=dict(zip(maneuvers, snakemake.input.segments)),
    best_json=snakemake.input.best,
    diagnosed_path=snakemake.input.diagnosed,
    diagnosis_json=snakemake.input.diagnosis,
    out_dir=Path(snakemake.output.json).parent,
    calibration_path=snakemake.input.calibration,
)
