"""Figure of the calibration: measured against simulated targets, before and after the fit."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hybridfmu.data.roles import CaseRoles
from hybridfmu.io import atomic_path

#: Most points drawn per line (longer series are thinned evenly).
MAX_POINTS = 5000


@dataclass
class Panel:
    """One maneuver of the figure.

    Attributes:
        maneuver, role: the maneuver's name and role.
        time_s: (T,) sample times in s.
        measured: (T, n_targets) measured targets (order ``roles.target_states``).
        before, after: (T, n_targets) simulated targets with the start and the calibrated values, or None.
    """

    maneuver: str
    role: str
    time_s: np.ndarray
    measured: np.ndarray
    before: np.ndarray | None = None
    after: np.ndarray | None = None


def _thin(n: int) -> slice:
    return slice(None, None, max(1, int(np.ceil(n / MAX_POINTS))))


def calibration_figure(path: str | Path, panels: list[Panel], roles: CaseRoles, title: str,
                       dpi: int = 120) -> Path:
    """Draw one row per maneuver and one column per target; write the PNG ``path`` atomically.

    Axes: time [s] against the target signal (``Signal.display()``, label and unit).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    targets = roles.target_states
    rows, cols = max(len(panels), 1), max(len(targets), 1)
    fig, axes = plt.subplots(rows, cols, figsize=(6.0 * cols + 1.0, 2.8 * rows + 0.8), squeeze=False)
    for r, panel in enumerate(panels):
        keep = _thin(panel.time_s.size)
        t = panel.time_s[keep]
        for c, state in enumerate(targets):
            ax = axes[r][c]
            signal = roles.signal_of_state(state)
            ax.plot(t, panel.measured[keep, c], color="black", lw=1.0, label="measured")
            if panel.before is not None:
                ax.plot(t, panel.before[keep, c], color="tab:orange", lw=1.0, ls="--", label="FMU before calibration")
            if panel.after is not None:
                ax.plot(t, panel.after[keep, c], color="tab:blue", lw=1.0, label="FMU calibrated")
            name = panel.maneuver if panel.maneuver == panel.role else f"{panel.maneuver} ({panel.role})"
            ax.set_title(f"{name}: {signal.label}", fontsize=10)
            ax.set_ylabel(signal.display())
            ax.set_xlabel("time [s]")
            ax.grid(True, alpha=0.3)
            if r == 0 and c == 0:
                ax.legend(fontsize=8, loc="best")
    if not panels:
        axes[0][0].text(0.5, 0.5, "no maneuver", ha="center", va="center")
    fig.suptitle(title)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    plt.close(fig)
    return Path(path)
