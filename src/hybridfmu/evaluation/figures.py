"""The paper's figures (Figs. 6, 9-16), training curves and the Hyperband overview.

Every function draws from arrays already computed (nothing is simulated here), writes one PNG
with the Agg backend and returns its path. Signals are :class:`hybridfmu.data.roles.Signal` (or anything
with ``name``, ``label``, ``unit`` and ``display()``): titles and axes come from them. Legends carry
the loss values in square brackets, as in the paper, e.g. ``FMU [MAE 1.23 rad, MSE 2.5 rad²]``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from hybridfmu.evaluation.metrics import format_error  # noqa: E402
from hybridfmu.io import atomic_path  # noqa: E402

DATA_STYLE = {"color": "black", "label": "data"}
FMU_STYLE = {"color": "tab:red"}
NEURAL_STYLE = {"color": "tab:blue"}
#: Styles and legend names of the further models (saved trajectories ``<model>_<signal>``).
FURTHER_STYLES = {"fmu_effects": ({"color": "tab:orange"}, "FMU + effects"),
                  "hybrid": ({"color": "tab:green"}, "hybrid"),
                  "ceiling": ({"color": "tab:gray", "linestyle": ":"}, "ceiling (true plant)")}



def squared_unit(unit: str) -> str:
    """The unit of a squared error: ``rad`` -> ``rad²``, ``rad/s`` -> ``(rad/s)²``, dimensionless -> ``-``."""
    if not unit:
        return "-"
    return f"({unit})²" if any(c in unit for c in "/* ·") else f"{unit}²"


@dataclass(frozen=True)
class PlotOptions:
    """Drawing options (config section ``evaluation.plot``); changing them redraws only.

    Attributes:
        dpi: resolution of the PNGs.
        width_in, height_in: size of a single-panel figure, inches (multi-panel figures grow).
        font_size: base font size, pt.
        line_width: width of the trajectory lines, pt.
        max_points: at most this many points per drawn line (min/max decimation keeps spikes).
    """

    dpi: int = 150
    width_in: float = 10.0
    height_in: float = 4.5
    font_size: float = 10.0
    line_width: float = 1.0
    max_points: int = 20000

    @classmethod
    def from_config(cls, options: dict | None) -> "PlotOptions":
        return cls(**(options or {}))


@dataclass
class Trajectories:
    """Data, FMU and neural FMU of one target signal on one maneuver, all on the grid ``time_s`` (T,).

    Attributes:
        maneuver: name of the maneuver (in titles).
        signal: the target signal (label and unit of the axis and legends).
        time_s: (T,) s; data, fmu, neural_fmu: (T,) in the signal's unit.
        zooms: zoomed intervals (t_start_s, t_end_s).
        further: further models (``fmu_effects``, ``hybrid``, ``ceiling``) -> (T,) in the signal's unit.
    """

    maneuver: str
    signal: Any
    time_s: np.ndarray
    data: np.ndarray
    fmu: np.ndarray
    neural_fmu: np.ndarray
    zooms: list[tuple[float, float]] = field(default_factory=list)
    further: dict[str, np.ndarray] = field(default_factory=dict)


def decimate_minmax(time_s: np.ndarray, values: np.ndarray, max_points: int) -> tuple[np.ndarray, np.ndarray]:
    """Reduce a line to at most ``max_points`` points keeping each bucket's min and max (spikes stay).

    Args:
        time_s, values: arrays of shape (T,).
        max_points: upper bound on the number of points returned (>= 4).
    """
    time_s = np.asarray(time_s, dtype=float)
    values = np.asarray(values, dtype=float)
    if time_s.size <= max_points or max_points < 4:
        return time_s, values
    buckets = max_points // 2
    edges = np.linspace(0, time_s.size, buckets + 1).astype(int)
    keep = []
    for start, end in zip(edges[:-1], edges[1:]):
        if end <= start:
            continue
        chunk = values[start:end]
        lo, hi = start + int(np.argmin(chunk)), start + int(np.argmax(chunk))
        keep.extend(sorted({lo, hi}))
    index = np.asarray(keep, dtype=int)
    return time_s[index], values[index]


def _loss_label(name: str, simulated: np.ndarray, data: np.ndarray, unit: str) -> str:
    diff = np.asarray(simulated, float) - np.asarray(data, float)
    mae, mse = float(np.mean(np.abs(diff))), float(np.mean(diff ** 2))
    return f"{name} [MAE {format_error(mae, unit or '-')}, MSE {format_error(mse, squared_unit(unit))}]"


def _style(options: PlotOptions) -> dict:
    return {"font.size": options.font_size, "axes.titlesize": options.font_size + 1,
            "legend.fontsize": options.font_size - 1, "axes.grid": True, "grid.alpha": 0.3}


def _save(fig: plt.Figure, path: str | Path, options: PlotOptions) -> Path:
    path = Path(path)
    fig.tight_layout()
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=options.dpi, format="png")
    plt.close(fig)
    return path


def _draw_lines(ax: plt.Axes, traj: Trajectories, mask: np.ndarray, options: PlotOptions) -> None:
    t = traj.time_s[mask]
    lines = [(traj.data, DATA_STYLE, None), (traj.fmu, FMU_STYLE, "FMU")]
    lines += [(traj.further[m], *FURTHER_STYLES[m]) for m in ("fmu_effects",) if m in traj.further]
    lines += [(traj.neural_fmu, NEURAL_STYLE, "neural FMU")]
    lines += [(traj.further[m], *FURTHER_STYLES[m]) for m in ("hybrid", "ceiling") if m in traj.further]
    for values, style, name in lines:
        x, y = decimate_minmax(t, values[mask], options.max_points)
        label = style.get("label") if name is None else _loss_label(name, values[mask], traj.data[mask],
                                                                    traj.signal.unit)
        # the data as a broad light band underneath, so that it stays visible where a model covers it
        ax.plot(x, y, color=style["color"], ls=style.get("linestyle", "-"),
                lw=options.line_width if name else options.line_width * 3.0,
                alpha=0.85 if name else 0.35, label=label, zorder=3 if name else 2)
    ax.set_xlabel("time t [s]")
    ax.set_ylabel(traj.signal.display())
    ax.legend(loc="best")


def plot_trajectory(traj: Trajectories, path: str | Path, options: PlotOptions = PlotOptions(),
                    title: str | None = None) -> Path:
    """Whole trajectory of one target signal: data, FMU and neural FMU (paper Figs. 9, 11, 13, 15).

    The zoomed intervals of ``traj.zooms`` are shaded. Legends give MAE and MSE over the whole
    trajectory in square brackets.
    """
    _check(traj)
    with plt.rc_context(_style(options)):
        fig, ax = plt.subplots(figsize=(options.width_in, options.height_in))
        _draw_lines(ax, traj, np.ones(traj.time_s.size, bool), options)
        for index, (start, end) in enumerate(traj.zooms):
            ax.axvspan(start, end, color="gold", alpha=0.25, lw=0, label="zoomed interval" if index == 0 else None)
        if traj.zooms:
            ax.legend(loc="best")
        ax.set_title(title or f"{traj.maneuver}: {traj.signal.label}, whole trajectory (open loop)")
        return _save(fig, path, options)


def plot_zooms(traj: Trajectories, path: str | Path, options: PlotOptions = PlotOptions(),
               title: str | None = None) -> Path:
    """Zoomed intervals ``traj.zooms`` of one target signal, one panel each (paper Figs. 10, 12, 14, 16).

    Legends give MAE and MSE over each interval in square brackets.
    """
    _check(traj)
    if not traj.zooms:
        raise ValueError(f"{traj.maneuver} {traj.signal.name}: no zoom interval to draw")
    with plt.rc_context(_style(options)):
        rows = len(traj.zooms)
        fig, axes = plt.subplots(rows, 1, figsize=(options.width_in, options.height_in * rows), squeeze=False)
        for ax, (start, end) in zip(axes[:, 0], traj.zooms):
            mask = (traj.time_s >= start) & (traj.time_s <= end)
            if not mask.any():
                raise ValueError(f"{traj.maneuver}: zoom interval [{start}, {end}] s holds no sample")
            _draw_lines(ax, traj, mask, options)
            ax.set_title(title or f"{traj.maneuver}: {traj.signal.label}, "
                                  f"{start:.3f} s to {end:.3f} s (open loop)")
        return _save(fig, path, options)


def plot_time_offset(time_s: np.ndarray, signals: Sequence[Any], data: np.ndarray, fmu: np.ndarray,
                     path: str | Path, fmu_delayed: np.ndarray | None = None, input_delay_s: float | None = None,
                     maneuver: str = "", options: PlotOptions = PlotOptions()) -> Path:
    """Target signals against the FMU on a short window, showing the time shift (paper Fig. 6).

    Per target signal two panels: the values, and FMU minus data (where a shift of a few samples shows).

    Args:
        time_s: (T,) time grid of the window, s.
        signals: (n_t,) the target signals (labels, units).
        data, fmu: (T, n_t) measured and simulated targets; the FMU starts from the measured state at the
            window's start and sees the inputs as logged.
        fmu_delayed: (T, n_t) the FMU with the estimated input delay ``input_delay_s`` (s), drawn dashed.
    """
    time_s = np.asarray(time_s, float)
    data = np.asarray(data, float).reshape(time_s.size, -1)
    n_t = len(signals)
    if data.shape[1] != n_t:
        raise ValueError(f"time-offset figure: {n_t} signals but data of shape {data.shape}")
    curves = [("FMU, inputs as logged", np.asarray(fmu, float).reshape(time_s.size, n_t), FMU_STYLE["color"], "-")]
    if fmu_delayed is not None:
        curves.append((f"FMU, inputs delayed by the estimated Δt = {input_delay_s * 1e6:.1f} µs",
                       np.asarray(fmu_delayed, float).reshape(time_s.size, n_t), "tab:orange", "--"))
    with plt.rc_context(_style(options)):
        fig, axes = plt.subplots(2 * n_t, 1, sharex=True, squeeze=False,
                                 figsize=(options.width_in, options.height_in * 1.6 * n_t),
                                 gridspec_kw={"height_ratios": [2, 1] * n_t})
        t_ms = (time_s - time_s[0]) * 1e3
        for k, signal in enumerate(signals):
            ax, ax_err = axes[2 * k, 0], axes[2 * k + 1, 0]
            ax.plot(t_ms, data[:, k], color="black", lw=options.line_width * 3.0, alpha=0.35, label="data")
            for label, values, color, style in curves:
                mse = format_error(float(np.mean((values[:, k] - data[:, k]) ** 2)), squared_unit(signal.unit))
                ax.plot(t_ms, values[:, k], color=color, ls=style, lw=options.line_width,
                        label=f"{label} [MSE {mse}]")
                ax_err.plot(t_ms, values[:, k] - data[:, k], color=color, ls=style, lw=options.line_width)
            ax_err.axhline(0.0, color="black", lw=0.8, alpha=0.5)
            ax.set_ylabel(signal.display())
            ax.set_title(f"{maneuver + ': ' if maneuver else ''}{signal.label}: time offset between data and model "
                         "(FMU started from the measured state)")
            ax.legend(loc="best")
            ax_err.set_ylabel(f"FMU − data [{signal.unit or '-'}]")
        axes[-1, 0].set_xlabel(f"time t − {time_s[0]:.4f} s [ms]")
        return _save(fig, path, options)


def _check(traj: Trajectories) -> None:
    for attribute in ("name", "label", "unit"):
        if not hasattr(traj.signal, attribute):
            raise ValueError(f"{traj.maneuver}: the signal must have name, label and unit, got {traj.signal!r}")
    shapes = {np.shape(a) for a in (traj.time_s, traj.data, traj.fmu, traj.neural_fmu, *traj.further.values())}
    if len(shapes) != 1:
        raise ValueError(f"{traj.maneuver} {traj.signal.name}: time, data and the models differ in shape {shapes}")


def _bracket_colors(brackets: Sequence[int]) -> dict[int, tuple]:
    cmap = plt.get_cmap("tab10")
    return {bracket: cmap(index % 10) for index, bracket in enumerate(sorted(brackets))}


def _bracket_handles(colors: dict[int, tuple], marker: str | None = None) -> list:
    from matplotlib.lines import Line2D

    return [Line2D([], [], color=color, marker=marker, label=f"bracket {bracket}") for bracket, color in colors.items()]


def plot_training_curves(search, path: str | Path, options: PlotOptions = PlotOptions()) -> Path:
    """Training loss against the resource for every trial (top), and the best trial alone (bottom).

    Args:
        search: :class:`hybridfmu.evaluation.history.SearchHistory`.
    """
    colors = _bracket_colors(search.brackets)
    best = next((t for t in search.trials if t.trial_id == search.best_trial_id), None)
    with plt.rc_context(_style(options)):
        fig, (ax_all, ax_best) = plt.subplots(2, 1, figsize=(options.width_in, options.height_in * 2))
        handles = _bracket_handles(colors)
        for trial in search.trials:
            if trial.curve.size:
                ax_all.plot(trial.curve[:, 0], trial.curve[:, 1], color=colors[trial.bracket], lw=0.7, alpha=0.6)
        if best is not None and best.curve.size:
            handles += ax_all.plot(best.curve[:, 0], best.curve[:, 1], color="black", lw=2.0,
                                   label=f"best trial {best.trial_id}")
        ax_all.set_yscale("log")
        ax_all.set_xlabel("resource: training data processed [s]")
        ax_all.set_ylabel("training loss (normalised) [-]")
        ax_all.set_title(f"Training curves of all {len(search.trials)} trials, colored by Hyperband bracket")
        ax_all.legend(handles=handles, loc="best")
        if best is not None:
            if best.curve.size:
                ax_best.plot(best.curve[:, 0], best.curve[:, 1], color="tab:blue", lw=options.line_width,
                             label="training loss")
            points = [(r["resource_s"], r["objective"]) for r in best.rungs if r["objective"] is not None]
            if points:
                ax_best.plot(*zip(*points), "o-", color="black",
                             label=f"validation objective at rung ends [last {points[-1][1]:.3g}]")
            ax_best.set_yscale("log")
            ax_best.legend(loc="best")
            hp = ", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}"
                           for k, v in best.hyperparameters.items())
            ax_best.set_title(f"Best trial {best.trial_id}: {hp}", fontsize=options.font_size - 1, wrap=True)
        else:
            ax_best.set_title("Best trial: none (every trial failed)")
        ax_best.set_xlabel("resource: training data processed [s]")
        ax_best.set_ylabel("loss (normalised) [-]")
        return _save(fig, path, options)


def plot_hyperband(search, path: str | Path, options: PlotOptions = PlotOptions()) -> Path:
    """Validation objective against the resource at every rung of every trial, colored by bracket.

    Lines join the rungs of one trial; failed or diverged rungs are crosses on the top edge; a star
    marks the best trial's last rung.
    """
    colors = _bracket_colors(search.brackets)
    with plt.rc_context(_style(options)):
        fig, ax = plt.subplots(figsize=(options.width_in, options.height_in * 1.3))
        finite = [r["objective"] for t in search.trials for r in t.rungs if r["objective"] is not None]
        top = max(finite) * 2.0 if finite else 1.0
        handles = _bracket_handles(colors, marker="o")
        any_failed = False
        for trial in search.trials:
            points = [(r["resource_s"], r["objective"]) for r in trial.rungs if r["objective"] is not None]
            if points:
                ax.plot(*zip(*points), "o-", color=colors[trial.bracket], ms=4, lw=0.8, alpha=0.8)
            failed = [r["resource_s"] for r in trial.rungs if r["objective"] is None]
            if failed:
                ax.plot(failed, [top] * len(failed), "x", color=colors[trial.bracket], ms=7)
                any_failed = True
        if any_failed:
            from matplotlib.lines import Line2D

            handles.append(Line2D([], [], color="gray", marker="x", ls="", label="failed / diverged (top edge)"))
        best = next((t for t in search.trials if t.trial_id == search.best_trial_id), None)
        if best is not None:
            points = [(r["resource_s"], r["objective"]) for r in best.rungs if r["objective"] is not None]
            if points:
                handles += ax.plot(*points[-1], "*", color="crimson", ms=16, mec="black", ls="",
                                   label=f"best {best.trial_id} [{points[-1][1]:.3g}]")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("resource: training data processed [s]")
        ax.set_ylabel("validation objective (normalised) [-]")
        ax.set_title(f"Hyperband: validation objective of {len(search.trials)} trials in "
                     f"{len(search.brackets)} brackets")
        ax.legend(handles=handles, loc="best")
        return _save(fig, path, options)
