"""Data statistics of the training maneuver: pre/post-processing initialisation and loss scales."""

from __future__ import annotations

from typing import Any

import numpy as np

from hybridfmu.training.data import ManeuverArrays


def data_statistics(arrays: ManeuverArrays, fmu_model: Any, max_rows: int = 100_000) -> dict[str, Any]:
    """Means and spreads over the selected segments of a maneuver.

    Returns a JSON-able dict: ``x_mean``, ``x_std`` (states, FMU order), ``u_mean``, ``u_std`` (inputs),
    ``xdot_mean``, ``xdot_std`` (the FMU's derivatives at the measured states and inputs), ``target_std``
    (the loss scales: one spread per target state, order ``target_states``, in the target's unit),
    ``target_states``, ``target_signals``, ``n_rows`` (samples used; evenly thinned to at most ``max_rows``),
    ``sample_period_s`` (the grid's step, s), ``selected_duration_s`` (the selected segments' total length, s).
    """
    index = np.flatnonzero(arrays.span_mask())
    if index.size == 0:
        raise ValueError(f"maneuver {arrays.name}: no samples in the selected segments")
    selected_duration_s = float(index.size * arrays.sample_period_s)
    stride = max(1, int(np.ceil(index.size / max_rows)))
    index = index[::stride]
    x = np.ascontiguousarray(arrays.x_init[index])
    u = np.ascontiguousarray(arrays.u[index])
    xdot = np.asarray(fmu_model.derivatives(x, u), dtype=np.float64)
    if not np.all(np.isfinite(xdot)):
        raise ValueError(f"maneuver {arrays.name}: the FMU's derivatives are not finite at the measured states")
    stats = {
        "x_mean": x.mean(0), "x_std": x.std(0), "u_mean": u.mean(0), "u_std": u.std(0),
        "xdot_mean": xdot.mean(0), "xdot_std": xdot.std(0),
        "target_std": arrays.targets[index].std(0), "target_states": list(arrays.target_states),
        "target_signals": list(arrays.target_signals),
        "n_rows": int(index.size), "state_names": arrays.state_names, "input_names": arrays.input_names,
        "sample_period_s": float(arrays.sample_period_s), "selected_duration_s": selected_duration_s,
    }
    for name, spread in zip(arrays.target_signals, stats["target_std"]):
        if not spread > 0:
            raise ValueError(f"maneuver {arrays.name}: target {name!r} has spread {spread} in the selected "
                             "segments; the loss needs a spread > 0")
    return {key: value.tolist() if isinstance(value, np.ndarray) else value for key, value in stats.items()}
