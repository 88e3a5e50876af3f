"""Checks of an exported FMU with FMPy alone (no code of the package): what a user's tool would see.

``replay_deviation`` runs the FMU in ``fmpy.simulate_fmu``'s co-simulation loop at the model's sample step,
driven by the logged inputs from the start state, and returns per state the largest deviation from a reference
trajectory relative to its range, after shifting the outputs back by the FMU's declared ``output_delay_s``.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import numpy as np
from fmpy import read_model_description, simulate_fmu
from fmpy.validation import validate_fmu


def declared(fmu: Path) -> dict:
    """The exported FMU's declared interface: inputs, outputs, start parameters, output_delay_s, provenance."""
    description = read_model_description(str(fmu))
    variables = {v.name: v for v in description.modelVariables}
    with zipfile.ZipFile(fmu) as archive:
        root = ET.fromstring(archive.read("modelDescription.xml"))
        names = archive.namelist()
    provenance = root.find("VendorAnnotations/Tool[@name='hybridfmu']/Provenance")
    return {"inputs": [v.name for v in description.modelVariables if v.causality == "input"],
            "outputs": [v.name for v in description.modelVariables if v.causality == "output"],
            "output_delay_s": float(variables["output_delay_s"].start),
            "provenance": dict(provenance.attrib) if provenance is not None else {},
            "co_simulation": description.coSimulation is not None, "files": names}


def replay_deviation(fmu: Path, time_s: np.ndarray, u: np.ndarray, reference: np.ndarray,
                     parameters: dict[str, float] | None = None) -> np.ndarray:
    """(n_x,) largest |output - reference| / range of the reference, over the samples both cover; ``parameters``:
    further start values (e.g. an effect coefficient)."""
    info = declared(fmu)
    step = float(time_s[1] - time_s[0])
    lag = int(round(info["output_delay_s"] / step))
    signals = np.zeros(len(time_s), dtype=[("time", float)] + [(name, float) for name in info["inputs"]])
    signals["time"] = np.arange(len(time_s)) * step  # FMPy's communication points: each sample as it is
    for column, name in enumerate(info["inputs"]):
        signals[name] = u[:, column]
    result = simulate_fmu(str(fmu), start_time=0.0, stop_time=float(time_s[-1] - time_s[0]), step_size=step,
                          output_interval=step, input=signals, output=info["outputs"],
                          start_values={**{f"{name}_start": float(value) for name, value in
                                           zip(info["outputs"], reference[0])}, **(parameters or {})})
    outputs = np.stack([result[name] for name in info["outputs"]], axis=1)[:len(time_s)]
    compared = len(time_s) - lag
    spread = np.ptp(reference[:compared], axis=0)
    return np.max(np.abs(outputs[lag:] - reference[:compared]), axis=0) / np.where(spread > 0, spread, 1.0)


def problems(fmu: Path) -> list[str]:
    """fmpy's validation messages (empty: valid)."""
    return [str(problem) for problem in validate_fmu(str(fmu))]
