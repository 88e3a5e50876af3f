"""The segment-selection figure (paper Fig. 8): angle, speed and load over time, selected spans shaded."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from hybridfmu.data.segments import SegmentSelection
from hybridfmu.io import atomic_path

#: (column, axis label) of the panels, top to bottom.
PANELS = (
    ("theta_rad", "angle θ (rad)"),
    ("omega_rad_s", "speed ω (rad/s)"),
    ("tau_load_nm", "load torque τ_load (N·m)"),
)


def plot_segments(frame: pd.DataFrame, selection: SegmentSelection, maneuver: str, png_path: str | Path,
                  max_points: int = 20000, dpi: int = 120) -> Path:
    """Draw the maneuver with the selected spans shaded and write it atomically to ``png_path``.

    Args:
        frame: ingested data (``time_s`` and the columns of ``PANELS``; missing panels are skipped).
        selection: the result of :func:`hybridfmu.data.segments.select_segments`.
        maneuver: name shown in the title.
        png_path: output PNG.
        max_points: at most this many points per line (min/max envelope of the samples per bin).
        dpi: resolution.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [(column, label) for column, label in PANELS if column in frame.columns]
    time_s = frame["time_s"].to_numpy(dtype=np.float64)
    fig, axes = plt.subplots(len(panels), 1, sharex=True, figsize=(11, 2.3 * len(panels) + 0.8), squeeze=False)
    for axis, (column, label) in zip(axes[:, 0], panels):
        t_plot, y_plot = envelope(time_s, frame[column].to_numpy(dtype=np.float64), max_points)
        axis.plot(t_plot, y_plot, color="tab:blue", linewidth=0.8, label="measured")
        for index, (start, end) in enumerate(selection.spans_s):
            axis.axvspan(start, end, color="tab:green", alpha=0.25, linewidth=0,
                         label="selected for training" if index == 0 else None)
        axis.set_ylabel(label)
        axis.grid(True, alpha=0.3)
    axes[0, 0].legend(loc="upper right", fontsize="small")
    axes[-1, 0].set_xlabel("time (s)")
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
