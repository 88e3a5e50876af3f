"""Rule diagnose: the diagnosis of the sim-to-real gap of the case (diagnosis.json, report.md, figures)."""

from pathlib import Path

import torch

from hybridfmu.api.stages import diagnose, setup_rule_logging

torch.set_num_threads(1)
setup_rule_logging(snakemake.log[0])
maneuvers = list(snakemake.params.maneuvers)
diagnose(
    config=dict(snakemake.params.config),
    fmu_path=snakemake.input.fmu,
    data_paths=dict(zip(maneuvers, snakemake.input.data)),
    segments_paths=dict(zip(maneuvers, snakemake.input.segments)),
    out_dir=Path(snakemake.output.json).parent,
    calibration_path=snakemake.input.calibration,
    workers=snakemake.threads,
)
