"""The case's sample grid chosen from its logs, where the config leaves ``ingest.rate_hz`` out, and how the FMU
inputs the config leaves out pass between its samples (:mod:`hybridfmu.data.between_samples`).

Every maneuver is resampled onto one uniform grid. Its rate comes from the logs themselves: per train and
validation maneuver (a test maneuver informs no choice) the median time step of each logged signal's channel,
the fastest channel giving the maneuver's rate; over the maneuvers the highest rate, rounded to six significant
digits (a 1 kHz logger's jittery stamps give 1000 Hz).
Rule ``choose_grid`` (:func:`hybridfmu.data.ingest.choose_grid`) writes the choice to ``{RESULTS}/data/grid.json``
once, for every ingest job, and the report quotes it as chosen from the data.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from hybridfmu.data.errors import DataError
from hybridfmu.data.settings import section_settings
from hybridfmu.io import read_json

#: Logs whose rates differ by more than this share are named in the choice (each is resampled onto the fastest).
RATE_SPREAD_NOTE = 0.01


def median_step_s(raw_path: str | Path, time_bases: dict[str, np.ndarray]) -> float:
    """The smallest of the channels' median time steps (s): the fastest channel's sample period.

    Raises:
        DataError: no channel has two increasing time stamps; names the file.
    """
    steps = []
    for time_s in time_bases.values():
        diffs = np.diff(time_s)
        diffs = diffs[np.isfinite(diffs) & (diffs > 0)]
        if diffs.size:
            steps.append(float(np.median(diffs)))
    if not steps:
        raise DataError(f"{raw_path}: no channel has two increasing time stamps; cannot choose the grid's rate "
                        "(set config.ingest.rate_hz)")
    return min(steps)


def choose_rate_hz(steps_s: dict[str, float]) -> tuple[float, str]:
    """The grid rate (Hz) for the maneuvers' median steps (maneuver -> s), and a sentence saying how it was chosen.

    The highest of the maneuvers' rates, rounded to six significant digits.
    """
    rates = {name: 1.0 / step for name, step in steps_s.items()}
    fastest = max(rates, key=rates.get)
    rate_hz = float(f"{rates[fastest]:.6g}")
    text = (f"{rate_hz:g} Hz: the median time step of the logs' fastest channel "
            f"({steps_s[fastest] * 1e3:.6g} ms in {fastest})")
    slower = {name: rate for name, rate in rates.items() if rate < rates[fastest] * (1.0 - RATE_SPREAD_NOTE)}
    if slower:
        text += "; slower logs resampled onto it: " + ", ".join(f"{name} {rate:.6g} Hz"
                                                                for name, rate in sorted(slower.items()))
    return rate_hz, text


def grid_rate_hz(config: dict[str, Any], grid_path: str | Path | None = None) -> float:
    """The grid rate (Hz): ``ingest.rate_hz`` where the config sets it, else the choice in ``grid_path``.

    Raises:
        ValueError: the config leaves the rate out and there is no choice to read.
    """
    configured = section_settings(config.get("ingest"), "ingest")["rate_hz"]
    if configured is not None:
        return float(configured)
    if grid_path is None or not Path(grid_path).is_file():
        raise ValueError("config.ingest.rate_hz is not set and no grid was chosen from the logs "
                         "(rule choose_grid writes data/grid.json)")
    return float(read_json(grid_path)["rate_hz"])


def chosen_conventions(grid_path: str | Path | None) -> dict[str, str]:
    """FMU input -> convention between samples chosen from the logs (``grid_path``'s ``between_samples``; rule
    ``choose_grid``); {} without a file."""
    if grid_path is None:
        return {}
    return {name: str(entry["convention"])
            for name, entry in (read_json(grid_path).get("between_samples") or {}).items()}
