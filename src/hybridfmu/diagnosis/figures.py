"""Figures of the diagnosis (matplotlib, Agg backend): equation error over time, regions, candidates,
fitted effects, the waterfall of the open-loop gap, open-loop trajectories and error growth."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from hybridfmu.io import atomic_path  # noqa: E402


def _save(fig, path: Path, dpi: int) -> Path:
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    plt.close(fig)
    return path


def _thin(n: int, max_points: int = 20000) -> slice:
    return slice(None, None, max(n // max_points, 1))


def equation_error_figure(result: dict[str, Any], path: Path, dpi: int) -> Path:
    """Kernel-averaged equation error of each group over time, per maneuver, with the noise floor."""
    from hybridfmu.diagnosis.run import _group_scale, _group_units

    layout = result["layout"]
    prepared = result["prepared"]
    groups = list(layout.groups)
    fig, axes = plt.subplots(len(prepared), len(groups), figsize=(6.0 * len(groups), 2.4 * len(prepared)),
                             squeeze=False, sharex="row")
    for i, (name, p) in enumerate(prepared.items()):
        for j, group in enumerate(groups):
            ax = axes[i, j]
            rows = layout.groups[group]
            scale = _group_scale(group, layout)
            residual = p.extras["residual_filtered"][:, rows] * scale
            sl = _thin(len(p.error.time_s))
            labels = [layout.state_names[r] for r in rows]
            for k, label in enumerate(labels):
                ax.plot(p.error.time_s[sl], residual[sl, k], lw=0.6, label=f"{label} equation")
                floor = p.noise_floor[rows[k]] * scale[k]
                ax.axhspan(-floor, floor, color=f"C{k}", alpha=0.12)
            ax.set_title(f"{name} ({p.measured.role}): {group} equation error")
            ax.set_xlabel("time (s)")
            ax.set_ylabel(f"residual ({_group_units(group, layout)})")
            ax.legend(loc="upper right", fontsize=7)
    fig.suptitle("Equation error (measured minus model, Hann-averaged); shaded: +-1 noise floor", fontsize=10)
    return _save(fig, path, dpi)


def regions_figure(result: dict[str, Any], path: Path, dpi: int) -> Path:
    """Energy share against time share of every region, per group."""
    regions = result["regions"]
    fig, axes = plt.subplots(1, len(regions), figsize=(7.0 * len(regions), 8.0), squeeze=False)
    for ax, (group, info) in zip(axes[0], regions.items()):
        table = info["table"]
        labels = [r["region"] for r in table]
        y = np.arange(len(table))
        ax.barh(y - 0.2, [100 * r["time_share"] for r in table], height=0.4, label="time share")
        ax.barh(y + 0.2, [100 * r["excess_share"] for r in table], height=0.4,
                label="share of the residual energy above noise")
        ax.set_yticks(y, labels, fontsize=6)
        ax.invert_yaxis()
        ax.set_xlabel("share (%)")
        ax.set_title(f"{group} equation: where the residual lies")
        ax.legend(fontsize=7, loc="lower right")
    return _save(fig, path, dpi)


def candidates_figure(result: dict[str, Any], path: Path, dpi: int) -> Path:
    """Share of the residual each candidate removes at the first selection step, per group."""
    groups = result["which"]["groups"]
    fig, axes = plt.subplots(1, max(len(groups), 1), figsize=(6.0 * max(len(groups), 1), 3.6), squeeze=False)
    for ax, (group, info) in zip(axes[0], groups.items()):
        if not info["steps"]:
            continue
        cands = info["steps"][0]["candidates"]
        names = [c["effect"] for c in cands]
        values = [100 * max(c["relative_improvement"], 0.0) for c in cands]
        colors = ["C2" if n in info["chosen"] else "C7" for n in names]
        ax.bar(range(len(names)), values, color=colors)
        ax.set_xticks(range(len(names)), names, rotation=35, ha="right", fontsize=7)
        ax.set_ylabel("residual removed at step 1 (%)")
        ax.set_title(f"{group}: candidates (green = chosen)")
        threshold = 100 * result["settings"].get("selection", {}).get("min_relative_improvement", 0.03)
        ax.axhline(threshold, color="k", lw=0.8, ls="--", label="minimum improvement")
        ax.legend(fontsize=7)
    return _save(fig, path, dpi)


def effects_figure(result: dict[str, Any], path: Path, dpi: int) -> Path:
    """Per chosen effect: the partial residual (residual minus the other chosen terms) against the term."""
    from hybridfmu.diagnosis.run import _group_scale, _group_units

    which = result["which"]
    terms = which["terms"]
    layout = result["layout"]
    cache = which["cache"]
    names = result["fit_names"]
    n = max(len(terms), 1)
    fig, axes = plt.subplots(1, n, figsize=(4.6 * n, 4.0), squeeze=False)
    if not terms:
        axes[0, 0].text(0.5, 0.5, "no effect chosen: the residual is explained by none of the candidates",
                        ha="center", va="center", fontsize=9, wrap=True)
        axes[0, 0].set_axis_off()
        return _save(fig, path, dpi)
    for ax, term in zip(axes[0], terms):
        rows = layout.groups[term.effect.group]
        scale = np.repeat(_group_scale(term.effect.group, layout)[None], len(cache.target(rows, names)) // len(rows),
                          axis=0).reshape(-1)
        y = cache.target(rows, names)
        others = [t for t in terms if t.effect.group == term.effect.group and t is not term]
        for other in others:
            a, b = cache.design(other.effect, other.setting, rows, names)
            y = y - (a @ other.coef if a.shape[1] else 0.0) - b
        a, b = cache.design(term.effect, term.setting, rows, names)
        fitted = (a @ term.coef if a.shape[1] else 0.0) + b
        ax.plot(fitted * scale, y * scale, ".", ms=2, alpha=0.5)
        lim = np.nanmax(np.abs(np.concatenate([fitted * scale, y * scale]))) or 1.0
        ax.plot([-lim, lim], [-lim, lim], "k-", lw=0.8)
        unit = _group_units(term.effect.group, layout)
        ax.set_xlabel(f"fitted {term.effect.name} term ({unit})")
        ax.set_ylabel(f"partial residual ({unit})")
        ax.set_title(f"{term.effect.name}", fontsize=9)
    fig.suptitle("Chosen effects: partial residual against the fitted term (fitting maneuvers)", fontsize=10)
    return _save(fig, path, dpi)


def waterfall_figure(result: dict[str, Any], path: Path, dpi: int) -> Path:
    """Open-loop angle MAE on the test maneuver(s): FMU, after each effect, neural FMU."""
    steps = result["how_far"]["steps"]
    fig, axes = plt.subplots(1, 2, figsize=(11.0, 4.0))
    labels = [s["model"] for s in steps]
    for ax, key, title in ((axes[0], "angle_mae_rad", "whole maneuver"),
                           (axes[1], "window_angle_mae_rad", f"restarted windows of "
                                                             f"{result['settings']['open_loop']['window_s']:g} s")):
        values = [s[key] for s in steps]
        finite = [v if np.isfinite(v) else np.nan for v in values]
        ax.bar(range(len(values)), finite, color=["C3"] + ["C2"] * (len(values) - 1))
        for k, v in enumerate(values):
            ax.text(k, finite[k] if np.isfinite(finite[k]) else 0, f"{v:.3g}", ha="center", va="bottom", fontsize=7)
        ax.set_yscale("log")
        ax.set_xticks(range(len(labels)), labels, rotation=25, ha="right", fontsize=7)
        ax.set_ylabel("angle MAE (rad)")
        ax.set_title(f"Open-loop gap on the test data, {title}", fontsize=9)
    return _save(fig, path, dpi)


def open_loop_figure(result: dict[str, Any], path: Path, dpi: int) -> Path:
    """Angle and speed of the test maneuver(s): measured, FMU, corrected FMU, neural FMU."""
    layout = result["layout"]
    far = result["how_far"]
    names = list(far["trajectories"])
    fig, axes = plt.subplots(2 * len(names), 1, figsize=(11.0, 5.0 * len(names)), squeeze=False)
    for i, name in enumerate(names):
        p = result["prepared"][name]
        t = p.measured.time_s
        sl = _thin(len(t))
        for k, (idx, quantity, unit) in enumerate(((layout.theta, "angle", "rad"), (layout.omega, "speed", "rad/s"))):
            ax = axes[2 * i + k, 0]
            ax.plot(t[sl], p.measured.x[sl, idx], "k", lw=1.2, label="measured")
            for j, (label, states) in enumerate(far["trajectories"][name].items()):
                if label == "FMU" or label == list(far["trajectories"][name])[-1] or label == "neural FMU":
                    ax.plot(t[sl], states[sl, idx], lw=0.8, label=label)
            ax.set_xlabel("time (s)")
            ax.set_ylabel(f"{quantity} ({unit})")
            ax.set_title(f"{name}: open-loop {quantity}", fontsize=9)
            ax.legend(fontsize=7, loc="upper right")
    return _save(fig, path, dpi)


def growth_figure(result: dict[str, Any], path: Path, dpi: int) -> Path:
    """Whole-maneuver open-loop angle error of the FMU over time, per maneuver."""
    fig, ax = plt.subplots(figsize=(10.0, 3.8))
    for item in result["growth"]:
        p = result["prepared"][item["maneuver"]]
        err = item["whole_angle_error_rad"]
        sl = _thin(len(err))
        ax.semilogy(p.measured.time_s[sl], np.maximum(err[sl], 1e-6), lw=0.8,
                    label=f"{item['maneuver']} ({item['role']})")
    ax.axhline(result["settings"]["open_loop"]["growth_threshold_rad"], color="k", ls="--", lw=0.8,
               label="threshold")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("|angle error| (rad)")
    ax.set_title("FMU open loop from the measured initial state: where the angle error grows", fontsize=9)
    ax.legend(fontsize=7)
    return _save(fig, path, dpi)
