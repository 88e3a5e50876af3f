"""Comparison of the FMU and the neural FMU with the data on whole maneuvers and zoomed intervals, and of the
further models a case has (:data:`MODELS`: the FMU plus the diagnosed effects, the hybrid) on whole maneuvers.

Pure array work on the target signals: the simulations are done elsewhere (``baseline``, ``evaluate``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from hybridfmu.evaluation.metrics import (improvement_factors, interval_mask, range_tolerance, summary_statistics,
                                          tolerance_errors, trajectory_errors, windowed_errors)
from hybridfmu.evaluation.zoom import choose_zoom_intervals, zoom_choices

#: Sources of the saved trajectories: column ``<source>_<signal>`` per target signal (the files also
#: hold ``fmu_state_<state>`` and ``neural_fmu_state_<state>`` for every FMU state).
SOURCES = ("data", "fmu", "neural_fmu")

#: Further models of the saved trajectories (columns ``<model>_<signal>`` and ``<model>_state_<state>`` when the
#: case has them): the FMU plus the diagnosed effects, the hybrid (the same under an ANN), and the ceiling: the
#: best any model could reach in these metrics (the true plant open loop, for an emulated case).
FURTHER_MODELS = ("fmu_effects", "hybrid", "ceiling")

#: Every compared model, in the order of the reports.
MODELS = ("fmu", "fmu_effects", "neural_fmu", "hybrid", "ceiling")


def trajectory_columns(signals: list[str]) -> list[str]:
    """Columns of the saved trajectories used here: ``time_s`` and ``<source>_<signal>``."""
    return ["time_s"] + [f"{source}_{signal}" for source in SOURCES for signal in signals]


@dataclass
class ManeuverRun:
    """Data and both simulations of one maneuver's target signals, on the data's grid.

    Attributes:
        maneuver: maneuver name.
        time_s: (T,) time grid, s, starting at the maneuver's first sample.
        signals: (n_t,) target signal names (columns of the arrays below).
        data, fmu, neural_fmu: (T, n_t) measured, FMU open loop, neural FMU open loop (model units).
        further: :data:`FURTHER_MODELS` name -> (T, n_t) open loop, for those the case has.
        windowed: model -> (T, n_t) over windows restarted from the measured state (multiple shooting,
            :mod:`hybridfmu.training.multiple_shooting`), for the models the trajectories have them of.
        closed_loop: model -> (T, n_t) driven by the case's controller (:mod:`hybridfmu.evaluation.closed_loop`),
            for the models the trajectories have them of.
    """

    maneuver: str
    time_s: np.ndarray
    signals: list[str]
    data: np.ndarray
    fmu: np.ndarray
    neural_fmu: np.ndarray
    further: dict[str, np.ndarray] = field(default_factory=dict)
    windowed: dict[str, np.ndarray] = field(default_factory=dict)
    closed_loop: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        expected = (np.shape(self.time_s)[0], len(self.signals))
        unknown = sorted(set(self.further) - set(FURTHER_MODELS))
        if unknown:
            raise ValueError(f"{self.maneuver}: unknown model(s) {unknown}; expected some of {list(FURTHER_MODELS)}")

        def checked(name: str, value: Any) -> np.ndarray:
            value = np.asarray(value, dtype=float)
            if value.ndim == 1 and len(self.signals) == 1:
                value = value[:, None]
            if value.shape != expected:
                raise ValueError(f"{self.maneuver}: {name} has shape {value.shape}, expected {expected}")
            return value

        for name in SOURCES:
            setattr(self, name, checked(name, getattr(self, name)))
        self.further = {name: checked(name, value) for name, value in self.further.items()}
        self.windowed = {name: checked(f"windowed {name}", value) for name, value in self.windowed.items()}
        self.closed_loop = {name: checked(f"closed-loop {name}", value) for name, value in self.closed_loop.items()}

    @property
    def models(self) -> list[str]:
        """The models this maneuver has, in the order of :data:`MODELS`."""
        return [m for m in MODELS if m in ("fmu", "neural_fmu") or m in self.further]

    @classmethod
    def from_frame(cls, frame: pd.DataFrame, maneuver: str, signals: list[str], source: str = "") -> "ManeuverRun":
        """From saved trajectories (:func:`trajectory_columns`); ``source`` names the file in errors."""
        missing = [c for c in trajectory_columns(signals) if c not in frame.columns]
        if missing:
            raise ValueError(f"{source or maneuver}: column(s) {missing} missing (expected saved trajectories)")
        arrays = [frame[[f"{kind}_{signal}" for signal in signals]].to_numpy(dtype=float) for kind in SOURCES]
        further = {name: frame[[f"{name}_{signal}" for signal in signals]].to_numpy(dtype=float)
                   for name in FURTHER_MODELS if all(f"{name}_{signal}" in frame.columns for signal in signals)}
        windowed, closed_loop = (
            {name: frame[[f"{prefix}_{name}_{signal}" for signal in signals]].to_numpy(dtype=float)
             for name in MODELS if all(f"{prefix}_{name}_{signal}" in frame.columns for signal in signals)}
            for prefix in ("windowed", "closed_loop"))
        return cls(maneuver, frame["time_s"].to_numpy(dtype=float), list(signals), *arrays, further=further,
                   windowed=windowed, closed_loop=closed_loop)

    def values(self, model: str) -> np.ndarray:
        """(T, n_t) of ``model``: one of :attr:`models`."""
        if model in self.further:
            return self.further[model]
        if model not in SOURCES[1:]:
            raise ValueError(f"{self.maneuver}: model must be one of {self.models}, got {model!r}")
        return getattr(self, model)

    def errors(self, model: str, mask: np.ndarray | None = None) -> dict[str, float]:
        """MAE/MSE/RMSE per target signal of ``model`` against the data, over ``mask`` (T,) or everything."""
        sel = slice(None) if mask is None else mask
        return trajectory_errors(self.values(model)[sel], self.data[sel], self.signals)

    def windowed_errors(self, model: str) -> dict[str, float | None]:
        """MAE/MSE/RMSE per target signal of ``model``'s windowed trajectory against the data, and the share of
        samples its windows did not reach (:func:`hybridfmu.evaluation.metrics.windowed_errors`)."""
        return windowed_errors(self.windowed[model], self.data, self.signals)

    def closed_loop_errors(self, model: str) -> dict[str, float]:
        """MAE/MSE/RMSE per target signal of ``model`` driven by the case's controller, against the data."""
        return trajectory_errors(self.closed_loop[model], self.data, self.signals)

    def tolerance_errors(self, model: str, tolerance: dict[str, float]) -> dict[str, float | int | None]:
        """Share of time ``model`` stays within ``tolerance`` ({signal: model unit}) of the data, and its errors
        while it does (:func:`hybridfmu.evaluation.metrics.tolerance_errors`)."""
        return tolerance_errors(self.values(model), self.data, self.signals, tolerance)


def tolerance_settings(settings: dict[str, Any] | None, signals: list[str],
                       validation_runs: list[ManeuverRun]) -> dict[str, Any]:
    """The tolerance of the in-tolerance metrics: ``{"signals": {signal: tolerance}, "source": text}``.

    Args:
        settings: config ``evaluation.tolerance`` (``signals``, ``fraction_of_range``).
        signals: the target signals.
        validation_runs: the validation maneuvers: a signal's default tolerance is chosen from their data alone.
    """
    settings = settings or {}
    configured = dict(settings.get("signals") or {})
    unknown = sorted(set(configured) - set(signals))
    if unknown:
        raise ValueError(f"config.evaluation.tolerance.signals: {unknown} are not target signals; expected some of "
                         f"{signals}")
    if configured:
        return {"signals": {k: float(v) for k, v in configured.items()}, "source": "config"}
    if not validation_runs:
        raise ValueError("config.evaluation.tolerance.signals is empty and there is no validation maneuver to choose "
                         "the tolerances from; name them in the config")
    fraction = float(settings.get("fraction_of_range", 0.05))
    chosen = {signal: range_tolerance([run.data[:, k] for run in validation_runs], fraction, signal)
              for k, signal in enumerate(signals)}
    return {"signals": chosen, "source": f"chosen from the data: {fraction:g} of each signal's range (1st to 99th "
                                         f"percentile) over the validation maneuvers"}


def physics_warnings(per_maneuver: dict[str, dict], signals: list[str]) -> list[str]:
    """One line per maneuver, model and target signal where a model is worse (whole-record MAE, open loop and, where
    simulated, closed loop) than the physics it is built on (:data:`OWN_PHYSICS`): a trained model worse than its
    own physics is a bug to look into."""
    lines = []
    for maneuver, entry in per_maneuver.items():
        for where, errors in (("", entry), ("closed-loop ", entry.get("closed_loop") or {})):
            for model, physics in OWN_PHYSICS.items():
                if model not in errors or physics not in errors:
                    continue
                for signal in signals:
                    key = f"{signal}_mae"
                    worse, base = float(errors[model][key]), float(errors[physics][key])
                    if worse > base:
                        lines.append(f"{maneuver}: {model} is worse than {physics}, its own physics, in {where}"
                                     f"{signal} MAE ({worse:.4g} against {base:.4g}, x{base / worse:.3g})")
    return lines


def distribution(per_maneuver: dict[str, dict], signals: list[str], models: list[str]) -> dict[str, dict]:
    """Median, min and max over the maneuvers of every model's errors, factors against the FMU (FMU error / model
    error) and in-tolerance metrics: ``{model: {key: {"median", "min", "max", "n"}}}``, keys ``<signal>_mae``,
    ``<signal>_mse``, ``<signal>_mae_factor``, ``<signal>_mse_factor`` (not for the FMU), ``in_tolerance_share``,
    ``tolerance_exits``, ``<signal>_mae_in_tolerance``, over the windows restarted from the measured state
    ``<signal>_mae_windowed`` and ``<signal>_mae_windowed_factor`` (not for the FMU), and driven by the case's
    controller ``<signal>_mae_closed_loop`` and ``<signal>_mae_closed_loop_factor`` (not for the FMU)."""
    out: dict[str, dict] = {}
    entries = list(per_maneuver.values())
    for model in models:
        keys: dict[str, list] = {}
        for entry in entries:
            errors = entry[model]
            for signal in signals:
                for measure in ("mae", "mse"):
                    keys.setdefault(f"{signal}_{measure}", []).append(errors[f"{signal}_{measure}"])
                    if model != "fmu":
                        improvement = entry["improvement" if model == "neural_fmu" else f"improvement_{model}"]
                        keys.setdefault(f"{signal}_{measure}_factor", []).append(improvement[f"{signal}_{measure}"])
            for kind in ("windowed", "closed_loop"):
                errors_of_kind = (entry.get(kind) or {}).get(model)
                if not errors_of_kind:
                    continue
                fmu_of_kind = entry[kind].get("fmu") or {}
                for signal in signals:
                    key = f"{signal}_mae"
                    keys.setdefault(f"{key}_{kind}", []).append(errors_of_kind[key])
                    if model != "fmu" and fmu_of_kind.get(key) is not None and errors_of_kind[key]:
                        keys.setdefault(f"{key}_{kind}_factor", []).append(fmu_of_kind[key] / errors_of_kind[key])
            tolerance = (entry.get("in_tolerance") or {}).get(model)
            if tolerance:
                for key in ("in_tolerance_share", "tolerance_exits", *(f"{s}_mae_in_tolerance" for s in signals)):
                    keys.setdefault(key, []).append(tolerance[key])
        out[model] = {key: summary_statistics(values) for key, values in keys.items()}
    return out


#: A trained or diagnosed model and the physics it is built on: it must never be worse than that physics.
OWN_PHYSICS = {"neural_fmu": "fmu", "fmu_effects": "fmu", "hybrid": "fmu_effects"}


def compare(reference: dict[str, float], candidate: dict[str, float]) -> dict[str, dict]:
    """``{"fmu": reference, "neural_fmu": candidate, "improvement": reference / candidate}``."""
    return {"fmu": reference, "neural_fmu": candidate, "improvement": improvement_factors(reference, candidate)}


def compare_further(fmu: dict[str, float], further: dict[str, dict[str, float]]) -> dict[str, dict]:
    """Per further model ``name``: ``{name: its errors, "improvement_<name>": fmu errors / its errors}``."""
    out: dict[str, dict] = {}
    for name, errors in further.items():
        out[name] = errors
        out[f"improvement_{name}"] = improvement_factors(fmu, errors)
    return out


def zoom_comparisons(run: ManeuverRun, zoom_settings: dict[str, Any] | None,
                     configured: list[dict] | None) -> list[dict]:
    """Metrics of both models on the maneuver's zoomed intervals (chosen from the FMU's error alone)."""
    lengths, criteria = zoom_choices(zoom_settings, run.signals)
    errors = {signal: run.fmu[:, k] - run.data[:, k] for k, signal in enumerate(run.signals)}
    zooms = []
    for interval in choose_zoom_intervals(run.time_s, errors, lengths, criteria, configured):
        mask = interval_mask(run.time_s, interval.t_start_s, interval.t_end_s)
        zooms.append({"maneuver": run.maneuver, **interval.as_dict(),
                      **compare(run.errors("fmu", mask), run.errors("neural_fmu", mask))})
    return zooms


def pooled_errors(runs: list[ManeuverRun], model: str) -> dict[str, float]:
    """MAE/MSE/RMSE over all samples of several maneuvers together (each sample weighs the same)."""
    return trajectory_errors(np.concatenate([r.values(model) for r in runs]),
                             np.concatenate([r.data for r in runs]), runs[0].signals)


def role_metrics(role: str, runs: list[ManeuverRun], zoom_settings: dict, extra: dict,
                 tolerance: dict[str, Any] | None = None) -> dict:
    """The metrics object of one role (``validation.json`` / ``test.json``).

    Args:
        role: "validation" or "test".
        runs: the maneuvers of that role (same target signals).
        zoom_settings: config ``evaluation.zoom`` (``length_s``, ``criterion``, ``intervals``).
        extra: learned quantities to include (``dt_s``, ``gates``, ``best_trial`` ...).
        tolerance: :func:`tolerance_settings` (``signals``, ``source``), or None: no in-tolerance metrics.

    Returns:
        ``{"role", "maneuvers", "signals", "samples", "duration_s", "fmu", "neural_fmu", "improvement",
        <extra>, "zooms": [...], "per_maneuver": {...}, "models", "distribution", "warnings"}``; ``fmu`` and
        ``neural_fmu`` hold ``<signal>_mae`` / ``_mse`` / ``_rmse`` per target signal over the whole
        trajectories of all maneuvers together (model units), ``improvement`` the FMU error over the neural FMU
        error for each of them; for each further model every maneuver has (``fmu_effects``, ``hybrid``,
        ``ceiling``) its errors and ``improvement_<model>`` likewise; each ``per_maneuver`` entry holds the same
        for its maneuver and, with a tolerance, ``in_tolerance`` ({model: :func:`tolerance_errors`}), with windowed
        trajectories ``windowed`` ({model: :func:`hybridfmu.evaluation.metrics.windowed_errors`}), with closed-loop
        trajectories ``closed_loop`` ({model: its MAE/MSE/RMSE per target signal}); with it
        ``tolerance``; ``distribution`` (:func:`distribution`) the median and range over the maneuvers;
        ``warnings`` (:func:`physics_warnings`) every maneuver where a model is worse than its own physics.
    """
    if not runs:
        raise ValueError(f"no maneuver with role {role!r} to evaluate")
    signals = runs[0].signals
    different = [r.maneuver for r in runs if r.signals != signals]
    if different:
        raise ValueError(f"maneuver(s) {different} have other target signals than {signals}")
    intervals = (zoom_settings or {}).get("intervals", {}) or {}
    zooms, per_maneuver = [], {}
    further = [m for m in FURTHER_MODELS if all(m in r.further for r in runs)]
    for run in runs:
        zooms += zoom_comparisons(run, zoom_settings, intervals.get(run.maneuver))
        fmu = run.errors("fmu")
        per_maneuver[run.maneuver] = {"duration_s": float(run.time_s[-1] - run.time_s[0]),
                                      **compare(fmu, run.errors("neural_fmu")),
                                      **compare_further(fmu, {m: run.errors(m) for m in further})}
        if tolerance:
            per_maneuver[run.maneuver]["in_tolerance"] = {
                m: run.tolerance_errors(m, tolerance["signals"]) for m in ("fmu", "neural_fmu", *further)}
        if run.windowed:
            per_maneuver[run.maneuver]["windowed"] = {m: run.windowed_errors(m) for m in MODELS if m in run.windowed}
        if run.closed_loop:
            per_maneuver[run.maneuver]["closed_loop"] = {m: run.closed_loop_errors(m) for m in MODELS
                                                         if m in run.closed_loop}
    models = [m for m in MODELS if m in ("fmu", "neural_fmu") or m in further]
    fmu = pooled_errors(runs, "fmu")
    return {"role": role, "maneuvers": [r.maneuver for r in runs], "signals": list(signals),
            "samples": int(sum(r.time_s.size for r in runs)),
            "duration_s": float(sum(r.time_s[-1] - r.time_s[0] for r in runs)),
            **compare(fmu, pooled_errors(runs, "neural_fmu")),
            **compare_further(fmu, {m: pooled_errors(runs, m) for m in further}),
            **extra, "zooms": zooms, "per_maneuver": per_maneuver, "models": models,
            **({"tolerance": tolerance} if tolerance else {}),
            "distribution": distribution(per_maneuver, list(signals), models),
            "warnings": physics_warnings(per_maneuver, list(signals))}
