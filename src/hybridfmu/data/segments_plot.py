"""The segment-selection figure (paper Fig. 8): the case's signals over time, the selected spans shaded.

Panels, top to bottom: each target state's signal, then the FMU inputs grouped by unit (one panel per
unit, e.g. three voltages together). Axis labels come from :meth:`hybridfmu.data.roles.Signal.display`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from hybridfmu.data.roles import CaseRoles
from hybridfmu.data.segments import SegmentSelection
from hybridfmu.io import atomic_path

LINE_COLOURS = ("tab:blue", "tab:orange", "tab:purple", "tab:brown", "tab:pink", "tab:olive")


def plot_panels(roles: CaseRoles, columns: list[str] | None = None) -> list[list[str]]:
    """Signals drawn in each panel: each target signal alone, then the input signals grouped by unit.

    Args:
        roles: the case's roles.
        columns: the frame's columns; signals not among them are left out.
    """
    present = set(columns) if columns is not None else set(roles.signals)
    panels = [[name] for name in dict.fromkeys(roles.target_signals) if name in present]
    shown = {name for panel in panels for name in panel}
    by_unit: dict[str, list[str]] = {}
    for name in dict.fromkeys(roles.input_signals):
        if name in present and name not in shown:
            by_unit.setdefault(roles.signals[name].unit, []).append(name)
    return panels + list(by_unit.values())


def panel_label(roles: CaseRoles, names: list[str]) -> str:
    """Axis label of a panel: ``label [unit]`` of its signal, or the labels joined for a group."""
    if len(names) == 1:
        return roles.signals[names[0]].display()
    unit = roles.signals[names[0]].unit or "-"
    return f"{', '.join(roles.signals[name].label for name in names)} [{unit}]"


def plot_segments(frame: pd.DataFrame, selection: SegmentSelection, maneuver: str, png_path: str | Path,
                  roles: CaseRoles, max_points: int = 20000, dpi: int = 120) -> Path:
    """Draw the maneuver with the selected spans shaded and write it atomically to ``png_path``.

    Args:
        frame: ingested data (``time_s`` (T,) and the signals' columns, model units).
        selection: the result of :func:`hybridfmu.data.segments.select_segments`.
        maneuver: name shown in the title.
        png_path: output PNG.
        roles: the case's roles (which signals to draw, their labels and units).
        max_points: at most this many points per line (min/max envelope of the samples per bin).
        dpi: resolution.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = plot_panels(roles, list(frame.columns))
    time_s = frame["time_s"].to_numpy(dtype=np.float64)
    fig, axes = plt.subplots(max(len(panels), 1), 1, sharex=True, figsize=(11, 2.1 * max(len(panels), 1) + 0.9),
                             squeeze=False)
    for axis, names in zip(axes[:, 0], panels):
        for colour, name in zip(LINE_COLOURS * 4, names):
            t_plot, y_plot = envelope(time_s, frame[name].to_numpy(dtype=np.float64), max_points)
            axis.plot(t_plot, y_plot, color=colour, linewidth=0.8, label=roles.signals[name].label)
        for index, (start, end) in enumerate(selection.spans_s):
            axis.axvspan(start, end, color="tab:green", alpha=0.25, linewidth=0,
                         label="selected" if index == 0 else None)
        axis.set_ylabel(panel_label(roles, names), fontsize="small")
        axis.grid(True, alpha=0.3)
        axis.legend(loc="upper right", fontsize="x-small", ncol=len(names) + 1)
    axes[-1, 0].set_xlabel("time [s]")
    axes[-1, 0].set_xlim(time_s[0], time_s[-1])
    fig.suptitle(f"Selected segments of maneuver '{maneuver}': {len(selection.spans_s)} spans, "
                 f"{100.0 * selection.fraction_kept:.1f} % of {selection.duration_s:.2f} s kept")
    fig.tight_layout()
    png_path = Path(png_path)
    with atomic_path(png_path) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    plt.close(fig)
    return png_path


def envelope(time_s: np.ndarray, values: np.ndarray, max_points: int) -> tuple[np.ndarray, np.ndarray]:
    """Reduce a long signal for plotting: min and max of each bin, so peaks stay visible.

    Shapes: (T,), (T,) -> (M,), (M,) with M <= max_points (unchanged when T <= max_points).
    """
    if len(values) <= max_points:
        return time_s, values
    bins = max(max_points // 2, 1)
    size = int(np.ceil(len(values) / bins))
    count = len(values) // size * size
    blocks = values[:count].reshape(-1, size)
    times = time_s[:count].reshape(-1, size)
    low_first = blocks.argmin(axis=1) < blocks.argmax(axis=1)
    first = np.where(low_first, blocks.min(axis=1), blocks.max(axis=1))
    second = np.where(low_first, blocks.max(axis=1), blocks.min(axis=1))
    t_out = np.stack([times[:, 0], times[:, -1]], axis=1).ravel()
    y_out = np.stack([first, second], axis=1).ravel()
    return t_out, y_out
