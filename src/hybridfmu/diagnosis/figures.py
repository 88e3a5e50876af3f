"""Figures of the diagnosis (matplotlib, Agg backend): equation error over time, regions, candidates,
fitted effects, the waterfall of the open-loop gap, open-loop trajectories and error growth.
Axes name states and equations with the labels and units of the case's roles."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from hybridfmu.diagnosis.selection import terms_in_equation  # noqa: E402
from hybridfmu.io import atomic_path  # noqa: E402

if TYPE_CHECKING:
    from hybridfmu.diagnosis.result import DiagnosisResult


def _save(fig, path: Path, dpi: int) -> Path:
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    plt.close(fig)
    return path


def _thin(n: int, max_points: int = 20000) -> slice:
    return slice(None, None, max(n // max_points, 1))


def equation_error_figure(result: DiagnosisResult, path: Path, dpi: int) -> Path:
    """Kernel-averaged equation error of each examined equation over time, per maneuver, with the noise floor."""
    problem = result.problem
    prepared = result.prepared
    eqs = problem.equations
    fig, axes = plt.subplots(len(prepared), len(eqs), figsize=(5.5 * len(eqs), 2.4 * len(prepared)),
                             squeeze=False, sharex="row")
    for i, (name, p) in enumerate(prepared.items()):
        for j, eq in enumerate(eqs):
            ax = axes[i, j]
            sl = _thin(len(p.error.time_s))
            ax.plot(p.error.time_s[sl], p.residual_filtered[sl, eq], lw=0.6)
            floor = p.noise_floor[eq]
            ax.axhspan(-floor, floor, color="C1", alpha=0.2)
            ax.set_title(f"{name} ({p.measured.role}): d{problem.state_names[eq]}/dt", fontsize=9)
            ax.set_xlabel("time (s)")
            ax.set_ylabel(f"residual [{problem.rate_unit(eq)}]", fontsize=8)
    fig.suptitle("Equation error (measured minus model, Hann-averaged); shaded: +-1 noise floor", fontsize=10)
    return _save(fig, path, dpi)


def regions_figure(result: DiagnosisResult, path: Path, dpi: int) -> Path:
    """Share of the residual energy above noise against time share of the most concentrated regions."""
    regions = result.regions
    fig, axes = plt.subplots(1, len(regions), figsize=(6.5 * len(regions), 7.0), squeeze=False)
    for ax, (state, info) in zip(axes[0], regions.items()):
        table = sorted(info["table"], key=lambda r: r["excess_share"] - r["time_share"], reverse=True)[:25]
        y = np.arange(len(table))
        ax.barh(y - 0.2, [100 * r["time_share"] for r in table], height=0.4, label="time share")
        ax.barh(y + 0.2, [100 * r["excess_share"] for r in table], height=0.4,
                label="share of the residual energy above noise (within its family)")
        ax.set_yticks(y, [r["region"] for r in table], fontsize=6)
        ax.invert_yaxis()
        ax.set_xlabel("share (%)")
        ax.set_title(f"d{state}/dt: where the residual lies", fontsize=9)
        ax.legend(fontsize=6, loc="lower right")
    return _save(fig, path, dpi)


def candidates_figure(result: DiagnosisResult, path: Path, dpi: int) -> Path:
    """Share of the residual the best candidates remove at the first selection step, per equation."""
    equations = result.which.equations
    n = max(len(equations), 1)
    fig, axes = plt.subplots(1, n, figsize=(6.0 * n, 4.0), squeeze=False)
    threshold = 100 * float((result.settings.get("selection") or {}).get("min_relative_improvement", 0.03))
    for ax, (state, info) in zip(axes[0], equations.items()):
        if not info["steps"]:
            ax.set_axis_off()
            continue
        cands = sorted(info["steps"][0]["candidates"], key=lambda c: c["relative_improvement"], reverse=True)[:15]
        names = [c["effect"] for c in cands]
        ax.bar(range(len(names)), [100 * max(c["relative_improvement"], 0.0) for c in cands],
               color=["C2" if nm in info["chosen"] else "C7" for nm in names])
        ax.set_xticks(range(len(names)), names, rotation=40, ha="right", fontsize=6)
        ax.set_ylabel("residual removed at step 1 (%)")
        ax.set_title(f"d{state}/dt: best candidates (green = chosen)", fontsize=9)
        ax.axhline(threshold, color="k", lw=0.8, ls="--", label="minimum improvement")
        ax.legend(fontsize=7)
    return _save(fig, path, dpi)


def effects_figure(result: DiagnosisResult, path: Path, dpi: int) -> Path:
    """Per chosen effect: the partial residual (residual minus the other chosen terms) against the term."""
    which = result.which
    terms = which.terms
    problem = result.problem
    cache = which.cache
    names = result.fit_names
    n = max(len(terms), 1)
    fig, axes = plt.subplots(1, n, figsize=(4.6 * n, 4.0), squeeze=False)
    if not terms:
        axes[0, 0].text(0.5, 0.5, "no effect chosen: the residual is explained by none of the candidates",
                        ha="center", va="center", fontsize=9, wrap=True)
        axes[0, 0].set_axis_off()
        return _save(fig, path, dpi)
    for ax, term, item in zip(axes[0], terms, which.chosen):  # terms in the rank order of ``chosen``
        eq = problem.state_names.index(item["equation"])  # the equation it explains most of
        y = cache.target(eq, names)
        others = [t for t in terms if t is not term]
        (term,) = terms_in_equation([term], eq)
        for other in terms_in_equation(others, eq):
            a = cache.design(other.effect, other.setting, names)
            y = y - (a @ other.coef if a.shape[1] else 0.0)
        a = cache.design(term.effect, term.setting, names)
        fitted = a @ term.coef if a.shape[1] else np.zeros_like(y)
        ax.plot(fitted, y, ".", ms=2, alpha=0.5)
        lim = float(np.nanmax(np.abs(np.concatenate([fitted, y])))) or 1.0
        ax.plot([-lim, lim], [-lim, lim], "k-", lw=0.8)
        unit = problem.rate_unit(eq)
        ax.set_xlabel(f"fitted term [{unit}]", fontsize=8)
        ax.set_ylabel(f"partial residual [{unit}]", fontsize=8)
        ax.set_title(f"{term.effect.name} in d{problem.state_names[eq]}/dt", fontsize=8)
    fig.suptitle("Chosen effects: partial residual against the fitted term (fitting maneuvers)", fontsize=10)
    return _save(fig, path, dpi)


#: Waterfall colours: the FMU, a step that shrank the gap, a step that widened it.
FMU_COLOUR, HELPED_COLOUR, HURT_COLOUR = "C0", "C2", "C3"


def step_colours(values: list[float]) -> list[str]:
    """Bar colours of a waterfall of gaps (the FMU first, then each cumulative step): a step is green when its gap
    is at most the step before's, red when it is larger (or not finite)."""
    colours = [FMU_COLOUR]
    for before, after in zip(values, values[1:]):
        helped = np.isfinite(after) and (not np.isfinite(before) or after <= before)
        colours.append(HELPED_COLOUR if helped else HURT_COLOUR)
    return colours


def waterfall_figure(result: DiagnosisResult, path: Path, dpi: int) -> Path:
    """Normalised open-loop gap on the test maneuver(s): the FMU and after each effect (green: the step shrank
    the gap, red: it widened it)."""
    steps = result.how_far.steps
    keys = [("gap", "whole maneuver")] + ([("window_gap", "restarted windows")] if "window_gap" in steps[0] else [])
    fig, axes = plt.subplots(1, len(keys), figsize=(5.5 * len(keys), 4.0), squeeze=False)
    labels = [s["model"] for s in steps]
    for ax, (key, title) in zip(axes[0], keys):
        values = [s.get(key, np.nan) for s in steps]
        finite = [v if v is not None and np.isfinite(v) else np.nan for v in values]
        ax.bar(range(len(values)), finite, color=step_colours(finite))
        for k, v in enumerate(finite):
            ax.text(k, 0 if np.isnan(v) else v, f"{v:.3g}", ha="center", va="bottom", fontsize=7)
        ax.set_xticks(range(len(labels)), labels, rotation=25, ha="right", fontsize=6)
        ax.set_ylabel("normalised gap (weighted MAE / spread)")
        ax.set_title(f"Open-loop gap on the test data, {title}", fontsize=9)
    handles = [plt.Rectangle((0, 0), 1, 1, color=c) for c in (FMU_COLOUR, HELPED_COLOUR, HURT_COLOUR)]
    axes[0][0].legend(handles, ["FMU", "step shrank the gap", "step widened the gap"], loc="upper right", fontsize=7)
    return _save(fig, path, dpi)


def open_loop_figure(result: DiagnosisResult, path: Path, dpi: int) -> Path:
    """Target states of the test maneuver(s): measured, FMU, FMU + all chosen effects."""
    problem = result.problem
    far = result.how_far
    names = list(far.trajectories)
    targets = [problem.state_names.index(s) for s in problem.target_weights]
    fig, axes = plt.subplots(len(targets) * len(names), 1, figsize=(11.0, 2.6 * len(targets) * len(names)),
                             squeeze=False)
    for i, name in enumerate(names):
        p = result.prepared[name]
        t = p.measured.time_s
        sl = _thin(len(t))
        variants = list(far.trajectories[name])
        shown = {"FMU", variants[-1]}
        for k, idx in enumerate(targets):
            ax = axes[len(targets) * i + k, 0]
            state = problem.state_names[idx]
            ax.plot(t[sl], p.measured.x[sl, idx], "k", lw=1.2, label="measured")
            for label in variants:
                if label in shown:
                    ax.plot(t[sl], far.trajectories[name][label][sl, idx], lw=0.8, label=label)
            ax.set_xlabel("time (s)")
            ax.set_ylabel(problem.display(state), fontsize=8)
            ax.set_title(f"{name}: open loop", fontsize=9)
            ax.legend(fontsize=6, loc="upper right")
    return _save(fig, path, dpi)


def growth_figure(result: DiagnosisResult, path: Path, dpi: int) -> Path:
    """Whole-maneuver open-loop error of the FMU over time (normalised by each target's spread), per maneuver."""
    fig, ax = plt.subplots(figsize=(10.0, 3.8))
    threshold = None
    for item in result.growth:
        p = result.prepared[item["maneuver"]]
        threshold = item["threshold_relative"]
        for signal, err in item["normalised_error"].items():
            sl = _thin(len(err))
            ax.semilogy(p.measured.time_s[sl], np.maximum(err[sl], 1e-6), lw=0.8,
                        label=f"{item['maneuver']} ({item['role']}): {signal}")
    if threshold is not None:
        ax.axhline(threshold, color="k", ls="--", lw=0.8, label="threshold")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("|error| / spread of the target")
    ax.set_title("FMU open loop from the measured initial state: where the error grows", fontsize=9)
    ax.legend(fontsize=6)
    return _save(fig, path, dpi)
