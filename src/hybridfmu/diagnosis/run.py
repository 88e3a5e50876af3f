"""The ``diagnose`` entry point: where the gap lies, which effect causes it, how far it shrinks.

``diagnose`` reads the case's FMU, ingested maneuvers and segments (and the trained neural FMU
when there is one), never the bench's ground truth, and writes ``diagnosis.json``,
``report.md`` and figures to the output folder. ``analyse`` does the computation and returns
the result as a dictionary (also used by the withheld-effect check).
"""

from __future__ import annotations

import copy
import logging
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from hybridfmu.diagnosis.corrected_model import EffectCorrection, open_loop_errors, shift_inputs
from hybridfmu.diagnosis.derivatives import smooth_at
from hybridfmu.diagnosis.effects import EffectInputs, candidate_effects, effect_options
from hybridfmu.diagnosis.layout import GROUPS, calibrate_constants, resolve_layout
from hybridfmu.diagnosis.prepare import PreparedManeuver, load_maneuver, prepare_maneuver
from hybridfmu.diagnosis.regions import (DEFAULT_REGION_SETTINGS, RegionSamples, ranked_statements,
                                         region_table, reversal_mask, time_bins)
from hybridfmu.diagnosis.selection import (DesignCache, GroupSelection, SelectionSettings, Term, best_setting,
                                           bootstrap_coefficients, drop_one_scores, fit_terms, select_group)

LOGGER = logging.getLogger("hybridfmu.diagnosis")

#: Units in which each group's residual is reported.
GROUP_UNITS = {"mechanical": "N m", "electrical": "V"}


def diagnosis_settings(config: dict[str, Any]) -> dict[str, Any]:
    """The ``diagnosis`` section of a validated case config, plus the master seed."""
    settings = copy.deepcopy(config.get("diagnosis", {}) or {})
    settings.setdefault("kernel_s", 0.004)
    settings.setdefault("smoothing_s", 0.002)
    settings.setdefault("speed_source", "angle")
    settings.setdefault("standstill_rad_s", 1.0)
    settings.setdefault("end_stop_margin_rad", 0.05)
    settings.setdefault("bootstrap_block_s", 0.25)
    settings.setdefault("variables", {})
    settings.setdefault("open_loop", {})
    settings["open_loop"].setdefault("window_s", 0.1)
    settings["open_loop"].setdefault("growth_threshold_rad", 0.05)
    regions = dict(DEFAULT_REGION_SETTINGS)
    regions.update(settings.get("regions", {}) or {})
    settings["regions"] = regions
    settings["seed"] = int(config.get("seed", 0))
    return settings


def _group_scale(group: str, layout) -> np.ndarray:
    """Factor from residual units (state derivative) to the reported unit, per state of the group."""
    if group == "mechanical":
        return np.array([layout.inertia_kg_m2 or 1.0])
    inv = [layout.constants.get("inv_l_d"), layout.constants.get("inv_l_q")]
    return np.array([1.0 / v if v else 1.0 for v in inv])


def _group_units(group: str, layout) -> str:
    if group == "mechanical":
        return "N m" if layout.inertia_kg_m2 else "rad/s^2"
    return "V" if layout.constants.get("inv_l_d") else "A/s"


def equation_summary(prepared: list[PreparedManeuver], layout) -> dict[str, Any]:
    """Per state: RMS of the kernel-averaged equation error, its noise floor, the spread of the
    measured derivative, and the normalised excess; per group the same in physical units."""
    states = {}
    for idx, name in enumerate(layout.state_names):
        residual = np.concatenate([p.fit.target[:, idx] for p in prepared])
        rate = np.concatenate([smooth_at(p.error.rate_meas[:, idx], p.error.kernel, p.fit.centres) for p in prepared])
        noise = math.sqrt(float(np.mean([p.noise_floor[idx] ** 2 for p in prepared])))
        rms = float(np.sqrt(np.mean(residual ** 2))) if residual.size else 0.0
        spread = float(np.std(rate)) if rate.size else 0.0
        excess = math.sqrt(max(rms ** 2 - noise ** 2, 0.0))
        states[name] = {"rms_residual": rms, "noise_floor": noise, "derivative_spread": spread,
                        "normalised_residual": rms / spread if spread > 0 else 0.0,
                        "normalised_excess": excess / spread if spread > 0 else 0.0,
                        "ratio_to_noise": rms / noise if noise > 0 else float("inf")}
    groups = {}
    for group, rows in layout.groups.items():
        scale = _group_scale(group, layout)
        names = [layout.state_names[i] for i in rows]
        rms_phys = float(np.sqrt(np.mean([(states[n]["rms_residual"] * s) ** 2 for n, s in zip(names, scale)])))
        noise_phys = float(np.sqrt(np.mean([(states[n]["noise_floor"] * s) ** 2 for n, s in zip(names, scale)])))
        excess = float(np.sqrt(np.mean([states[n]["normalised_excess"] ** 2 for n in names])))
        groups[group] = {"states": names, "rms_residual": rms_phys, "noise_floor": noise_phys,
                         "unit": _group_units(group, layout), "normalised_excess": excess,
                         "ratio_to_noise": rms_phys / noise_phys if noise_phys > 0 else float("inf")}
    # The carrier is the equation whose error stands out most above its own noise floor (its spread
    # normalisation depends on how fast that state moves, which is no measure of the gap).
    carrier = max(groups, key=lambda g: groups[g]["ratio_to_noise"]) if groups else None
    return {"states": states, "groups": groups, "carrier": carrier}


def region_samples(prepared: list[PreparedManeuver], group: str, layout, settings: dict[str, Any],
                   stride: int) -> tuple[RegionSamples, list[dict[str, Any]]]:
    """Residual energy and region features of a group pooled over maneuvers (every ``stride`` samples)."""
    rows = layout.groups[group]
    scale = _group_scale(group, layout)
    energy, noise, signed, feats = [], [], [], {k: [] for k in
                                               ("omega_rad_s", "accel_rad_s2", "tau_load_nm", "theta_rad",
                                                "reversal", "near_stop", "standstill")}
    per_time = []
    reg = settings["regions"]
    for p in prepared:
        residual = p.extras["residual_filtered"][:, rows] * scale
        keep = np.flatnonzero(np.all(np.isfinite(residual), axis=1))[::stride]
        e = np.sum(residual[keep] ** 2, axis=1)
        n = np.full(len(keep), float(np.sum((p.noise_floor[rows] * scale) ** 2)))
        energy.append(e)
        noise.append(n)
        signed.append(residual[keep, 0] if group == "mechanical" else np.sqrt(e))
        accel = p.error.filtered_rate()[:, layout.omega]
        feats["omega_rad_s"].append(p.omega_smooth[keep])
        feats["accel_rad_s2"].append(accel[keep])
        feats["tau_load_nm"].append(p.error.u[keep, layout.tau_load] if layout.tau_load is not None
                                    else np.zeros(len(keep)))
        feats["theta_rad"].append(p.error.x[keep, layout.theta])
        rev = reversal_mask(p.omega_smooth, p.error.dt_s, reg["reversal_speed_rad_s"], reg["reversal_window_s"])
        feats["reversal"].append(rev[keep])
        feats["near_stop"].append(p.masks["near_stop"][keep])
        feats["standstill"].append(p.masks["standstill"][keep])
        for row in time_bins(p.error.time_s[keep], e, n, reg["time_bin_s"]):
            per_time.append({"maneuver": p.measured.name, **row})
    samples = RegionSamples(energy=np.concatenate(energy), noise_energy=np.concatenate(noise),
                            signed=np.concatenate(signed), features={k: np.concatenate(v) for k, v in feats.items()})
    return samples, per_time


def _physical(term: Term, cov: np.ndarray, layout, options, context) -> list[dict[str, Any]]:
    return term.effect.physical(term.coef, cov, term.setting, term.setting_se, layout, options, context)


def _bootstrap_se(term: Term, draws: np.ndarray, layout, options, context) -> dict[str, float]:
    """Bootstrap standard error of each physical parameter of a term."""
    if draws.size == 0:
        return {}
    values: dict[str, list[float]] = {}
    zero = np.zeros((len(term.coef), len(term.coef)))
    for coef in draws:
        for row in term.effect.physical(coef, zero, term.setting, {}, layout, options, context):
            values.setdefault(row["name"], []).append(row["value"])
    # Parameters that only depend on the (fixed) nonlinear setting do not vary over the resamples.
    return {name: float(np.std(v, ddof=1)) for name, v in values.items() if len(v) > 1 and np.ptp(v) > 0}


def _fit_on(cache: DesignCache, selection: GroupSelection, names: list[str], options, layout,
            settings: SelectionSettings) -> list[Term]:
    """The chosen terms refitted on the maneuvers ``names`` alone (nonlinear settings re-optimised)."""
    terms = [Term(t.effect, dict(t.setting)) for t in selection.terms]
    for j, term in enumerate(terms):
        if len(term.effect.grid(options, layout)) > 1 or term.effect.continuous:
            others = terms[:j] + terms[j + 1:]
            terms[j], _, _ = best_setting(cache, others, term.effect, selection.rows, names, options, layout,
                                          settings.refine_iterations)
    fit = fit_terms(cache, terms, selection.rows, names)
    for term, coef in zip(terms, fit.coefs):
        term.coef = coef
    return terms


def _coef_cov(selection: GroupSelection, index: int) -> np.ndarray:
    sizes = [len(t.coef) for t in selection.terms]
    start = sum(sizes[:index])
    return selection.fit.cov[start:start + sizes[index], start:start + sizes[index]]


def select_effects(prepared: dict[str, PreparedManeuver], fit_names: list[str], layout, config: dict[str, Any],
                   settings: dict[str, Any]) -> dict[str, Any]:
    """Selection per group on the fitting maneuvers, ranking, uncertainty and stability."""
    options = effect_options(settings)
    sel_settings = SelectionSettings.from_config(settings.get("selection"))
    effects, skipped = candidate_effects(settings.get("candidates"), layout)
    cache = DesignCache([prepared[n].fit for n in prepared], options)
    context = dict(prepared[fit_names[0]].inputs.context)
    groups: dict[str, Any] = {}
    chosen: list[dict[str, Any]] = []
    terms_by_group: dict[str, list[Term]] = {}
    for group in GROUPS:
        if group not in layout.groups:
            continue
        group_effects = [e for e in effects if e.group == group]
        if not group_effects:
            continue
        rows = layout.groups[group]
        selection = select_group(cache, group, rows, group_effects, fit_names, options, layout, sel_settings)
        scores = drop_one_scores(cache, selection, fit_names) if selection.terms else {}
        draws = bootstrap_coefficients(cache, selection.terms, rows, fit_names, sel_settings.bootstrap_samples,
                                       settings["seed"] + len(groups))
        per_maneuver = {name: _fit_on(cache, selection, [name], options, layout, sel_settings)
                        for name in fit_names} if selection.terms else {}
        separate = {}
        if len(fit_names) > 1:
            for name in fit_names:
                alone = select_group(cache, group, rows, group_effects, [name], options, layout, sel_settings)
                separate[name] = [t.effect.name for t in alone.terms]
        terms_by_group[group] = selection.terms
        for j, term in enumerate(selection.terms):
            params = _physical(term, _coef_cov(selection, j), layout, options, context)
            boot = _bootstrap_se(term, draws[j], layout, options, context)
            stability = {}
            for row in params:
                values = {}
                for name, terms in per_maneuver.items():
                    t = terms[j]
                    refit = {r["name"]: r["value"] for r in t.effect.physical(
                        t.coef, np.zeros((len(t.coef), len(t.coef))), t.setting, {}, layout, options, context)}
                    if row["name"] in refit:
                        values[name] = refit[row["name"]]
                if len(values) > 1:
                    arr = np.array(list(values.values()))
                    denom = float(np.mean(np.abs(arr)))
                    stability[row["name"]] = {"per_maneuver": values,
                                              "relative_spread": float(np.ptp(arr) / denom) if denom > 0 else 0.0}
                row["se_bootstrap"] = boot.get(row["name"])
            chosen.append({
                "effect": term.effect.name, "group": group, "description": term.effect.description,
                "equation": term.effect.equation, "setting": dict(term.setting),
                "coefficients": dict(zip(term.effect.coefficient_names(term.setting), map(float, term.coef))),
                "parameters": params, "stability": stability, "score": float(scores.get(term.effect.name, 0.0)),
            })
        steps = [{"candidates": [{k: v for k, v in c.items()} for c in st.candidates], "chosen": st.chosen,
                  "reason": st.reason} for st in selection.steps]
        explained = 1.0 - selection.fit.rss / selection.rss_none if selection.rss_none > 0 else 0.0
        groups[group] = {"n_samples": selection.n, "rss_without_effects": selection.rss_none,
                         "rss_with_chosen": selection.fit.rss, "explained_share": explained,
                         "noise_variance": selection.noise_variance,
                         "mean_square_after": selection.fit.rss / max(selection.n, 1),
                         "chosen": [t.effect.name for t in selection.terms], "steps": steps,
                         "selection_per_maneuver": separate}
    chosen.sort(key=lambda c: c["score"], reverse=True)
    for rank, item in enumerate(chosen, start=1):
        item["rank"] = rank
    ordered_terms = []
    for item in chosen:
        ordered_terms.append(next(t for t in terms_by_group[item["group"]] if t.effect.name == item["effect"]))
    return {"chosen": chosen, "groups": groups, "skipped": skipped, "terms": ordered_terms, "options": options,
            "cache": cache, "context": context}


def neural_comparison(best_json: Path, fmu_path: Path, fmu_parameters: dict[str, float],
                      prepared: dict[str, PreparedManeuver], fit_names: list[str], terms: list[Term], layout,
                      options: dict[str, Any]) -> dict[str, Any]:
    """Load the neural FMU named by ``best_json`` and compare its learned correction with the chosen effects."""
    from hybridfmu.training.inference import load_trained_neural_fmu

    model = load_trained_neural_fmu(best_json, fmu_path, fmu_parameters or None)
    return learned_correction_r2(model, prepared, fit_names, terms, layout, options)


def learned_correction_r2(model: Any, prepared: dict[str, PreparedManeuver], fit_names: list[str],
                          terms: list[Term], layout, options: dict[str, Any]) -> dict[str, Any]:
    """How much of a hybrid model's learned speed correction each chosen effect explains (R^2).

    ``model`` is a neural FMU (``derivative(x, u_delayed)``, ``fmu(x, u)`` as torch tensors,
    ``delay_s()``, ``gate_values()``). The learned correction is ``xdot_hybrid[omega] - xdot_F[omega]``
    (g_F xdot_F + g_A xdot_A - xdot_F) along the measured trajectory at the fitting centres, both
    with the learned input delay. R^2 "fitted" uses the diagnosis's coefficients, "refit" the best
    linear fit of the effect's terms (plus a constant) to the learned correction.
    """
    import torch

    delay_s = float(model.delay_s())
    learned, effect_terms = [], {t.effect.name: [] for t in terms}
    regressors = {t.effect.name: [] for t in terms}
    for name in fit_names:
        p = prepared[name]
        idx = p.fit.centres
        x = p.error.x[idx]
        u = shift_inputs(p.measured.u, delay_s, p.error.dt_s)[:-1][idx]
        with torch.no_grad():
            xt, ut = torch.from_numpy(np.ascontiguousarray(x)), torch.from_numpy(np.ascontiguousarray(u))
            hybrid = model.derivative(xt, ut).numpy()
            plain = model.fmu(xt, ut).numpy()
        learned.append(hybrid[:, layout.omega] - plain[:, layout.omega])
        inputs = EffectInputs(layout, x, p.error.u[idx], omega_rad_s=p.omega_smooth[idx], f=p.error.f_model[idx],
                              dfdx=p.error.dfdx[idx], dfdu=p.error.dfdu[idx], context=p.inputs.context)
        for t in terms:
            if t.effect.group != "mechanical":
                continue
            effect_terms[t.effect.name].append(t.effect.correction(inputs, t.coef, t.setting, options)[:, layout.omega])
            a, _ = t.effect.terms(inputs, t.setting, options)
            regressors[t.effect.name].append(a[:, layout.omega, :] if a is not None else np.zeros((len(idx), 0)))
    c = np.concatenate(learned)
    total = float(np.sum((c - c.mean()) ** 2))
    rows = []
    joint = []
    for t in terms:
        if t.effect.group != "mechanical":
            rows.append({"effect": t.effect.name, "r2_fitted": None, "r2_refit": None,
                         "note": "acts on the electrical equations; the ANN corrects the speed equation only"})
            continue
        term = np.concatenate(effect_terms[t.effect.name])
        design = np.concatenate(regressors[t.effect.name])
        joint.append(design)
        r2_fit = 1.0 - float(np.sum((c - term) ** 2)) / total if total > 0 else None
        r2_refit = None
        if design.shape[1] and total > 0:
            full = np.column_stack([design, np.ones(len(c))])
            coef, *_ = np.linalg.lstsq(full, c, rcond=None)
            resid = c - full @ coef
            r2_refit = 1.0 - float(resid @ resid) / total
        rows.append({"effect": t.effect.name, "r2_fitted": r2_fit, "r2_refit": r2_refit})
    r2_joint = None
    if joint and total > 0:
        design = np.column_stack(joint + [np.ones((len(c), 1))])
        coef, *_ = np.linalg.lstsq(design, c, rcond=None)
        resid = c - design @ coef
        r2_joint = 1.0 - float(resid @ resid) / total
    scale = layout.inertia_kg_m2 or 1.0
    return {"learned_delay_s": delay_s, "gates": model.gate_values(),
            "learned_correction_rms": float(np.sqrt(np.mean(c ** 2))) * scale,
            "unit": "N m" if layout.inertia_kg_m2 else "rad/s^2", "effects": rows, "r2_joint": r2_joint,
            "model": model}


def how_far(models: dict[str, Any], prepared: dict[str, PreparedManeuver], test_names: list[str],
            terms: list[Term], layout, options: dict[str, Any], settings: dict[str, Any],
            neural: dict[str, Any] | None) -> dict[str, Any]:
    """Open-loop errors on the test maneuvers before, after each chosen effect (cumulative, rank order),
    and of the neural FMU."""
    from hybridfmu.fmu import simulate_open_loop

    ol = settings["open_loop"]
    steps = []
    trajectories: dict[str, dict[str, np.ndarray]] = {name: {} for name in test_names}
    variants = [("FMU", [])] + [(f"+ {t.effect.name}", terms[:k + 1]) for k, t in enumerate(terms)]
    for label, active in variants:
        correction = EffectCorrection(active, layout, options, models["helper"]) if active else None
        shift = float(sum(t.effect.input_shift_s(t.setting) for t in active))
        per = {}
        for name in test_names:
            meas = prepared[name].measured
            u = shift_inputs(meas.u, shift, prepared[name].error.dt_s)
            started = time.perf_counter()
            errors, whole = open_loop_errors(models["model"], simulate_open_loop, meas.time_s, meas.x, u, layout,
                                             correction, ol["window_s"], settings["smoothing_s"])
            LOGGER.info("open loop %s on %s: angle MAE %.4g rad, windowed %.4g rad (%.1f s)", label, name,
                        errors.angle_mae_rad, errors.window_angle_mae_rad, time.perf_counter() - started)
            per[name] = errors.as_dict()
            trajectories[name][label] = whole
        steps.append({"model": label, "effects": [t.effect.name for t in active], "per_maneuver": per,
                      **_mean_errors(per)})
    if neural is not None:
        per = {}
        for name in test_names:
            per[name], trajectories[name]["neural FMU"] = _neural_errors(neural["model"], prepared[name], layout,
                                                                          settings)
        steps.append({"model": "neural FMU", "effects": [], "per_maneuver": per, **_mean_errors(per)})
    before = steps[0]["angle_mae_rad"]
    after = steps[len(terms)]["angle_mae_rad"]
    return {"steps": steps, "gap_before_rad": before, "gap_after_rad": after,
            "shrink_factor": before / after if after and after > 0 else float("inf"),
            "window_gap_before_rad": steps[0]["window_angle_mae_rad"],
            "window_gap_after_rad": steps[len(terms)]["window_angle_mae_rad"],
            "trajectories": trajectories}


def _mean_errors(per: dict[str, dict[str, float]]) -> dict[str, float]:
    keys = next(iter(per.values())).keys()
    return {k: float(np.mean([v[k] for v in per.values()])) for k in keys if k != "n_windows"}


def neural_windows(model: Any, u: np.ndarray, x0: np.ndarray, first: np.ndarray, n_steps: int) -> np.ndarray:
    """Open-loop windows of a neural FMU side by side: (W, n_steps + 1, n_x) states.

    Window w starts at sample ``first[w]`` from ``x0[w]`` and sees only its own inputs
    ``u[first[w] : first[w] + n_steps + 1]`` (n_u columns), held at its ends for the input delay,
    exactly as ``simulate_neural_fmu`` on that piece; all windows are one batched rollout.
    """
    import torch

    from hybridfmu.training.inference import delay_padding
    from hybridfmu.training.solver import rollout

    first = np.asarray(first, dtype=int)
    spec = model.spec
    pad = delay_padding(spec.sample_period_s, spec.delay_min_s, spec.delay_max_s)
    index = np.clip(np.arange(-pad, n_steps + 1 + pad), 0, n_steps)
    u_seq = torch.from_numpy(np.ascontiguousarray(np.asarray(u, dtype=np.float64)[first[:, None] + index[None, :]]))
    x_start = torch.from_numpy(np.ascontiguousarray(np.asarray(x0, dtype=np.float64)))
    with torch.no_grad():
        return rollout(model, u_seq, pad, x_start, n_steps).numpy()


def simulate_neural_fmu(model: Any, time_s: np.ndarray, u: np.ndarray, x0: np.ndarray) -> np.ndarray:
    """Whole-maneuver open loop of a neural FMU (``hybridfmu.training.inference.simulate_neural_fmu``)."""
    from hybridfmu.training.inference import simulate_neural_fmu as simulate_whole

    return simulate_whole(model, time_s, u, x0)


def _neural_errors(model: Any, p: PreparedManeuver, layout, settings) -> tuple[dict[str, float], np.ndarray]:
    from hybridfmu.diagnosis.corrected_model import measured_initial_states

    meas = p.measured
    starts = measured_initial_states(meas.x, layout, p.error.dt_s, settings["smoothing_s"])
    whole = simulate_neural_fmu(model, meas.time_s, meas.u, starts[0])
    n_win = max(int(round(settings["open_loop"]["window_s"] / p.error.dt_s)), 2)
    first = np.arange(0, len(meas.time_s) - n_win, n_win)
    windows = neural_windows(model, meas.u, starts[first], first, n_win)
    angle_abs, speed_abs = [], []
    for w, start in enumerate(first):
        piece = slice(start, start + n_win + 1)
        states = windows[w]
        angle_abs.append(np.mean(np.abs(states[:, layout.theta] - meas.x[piece, layout.theta])))
        speed_abs.append(np.mean(np.abs(states[:, layout.omega] - starts[piece, layout.omega])))
    angle_err = whole[:, layout.theta] - meas.x[:, layout.theta]
    speed_err = whole[:, layout.omega] - starts[:, layout.omega]
    return {"angle_mae_rad": float(np.mean(np.abs(angle_err))), "angle_mse_rad2": float(np.mean(angle_err ** 2)),
            "speed_mae_rad_s": float(np.mean(np.abs(speed_err))), "speed_mse_rad2_s2": float(np.mean(speed_err ** 2)),
            "window_angle_mae_rad": float(np.mean(angle_abs)), "window_speed_mae_rad_s": float(np.mean(speed_abs)),
            "n_windows": len(angle_abs)}, whole


def error_growth(models: dict[str, Any], prepared: dict[str, PreparedManeuver], layout,
                 settings: dict[str, Any]) -> list[dict[str, Any]]:
    """Where the FMU's open-loop angle error grows: per maneuver, the restarted windows ranked by
    their final angle error, and the time the whole-maneuver error first exceeds the threshold."""
    from hybridfmu.diagnosis.corrected_model import measured_initial_states, simulate
    from hybridfmu.fmu import simulate_open_loop

    ol = settings["open_loop"]
    out = []
    for name, p in prepared.items():
        meas = p.measured
        starts = measured_initial_states(meas.x, layout, p.error.dt_s, settings["smoothing_s"])
        n_win = max(int(round(ol["window_s"] / p.error.dt_s)), 2)
        windows = []
        for start in range(0, len(meas.time_s) - n_win, n_win):
            piece = slice(start, start + n_win + 1)
            states = simulate(models["model"], simulate_open_loop, meas.time_s[piece], meas.u[piece], starts[start],
                              None)
            final = float(abs(states[-1, layout.theta] - meas.x[piece, layout.theta][-1]))
            windows.append({"t_start_s": float(meas.time_s[start]), "t_end_s": float(meas.time_s[piece][-1]),
                            "final_angle_error_rad": final if math.isfinite(final) else None})
        whole = simulate(models["model"], simulate_open_loop, meas.time_s, meas.u, starts[0], None)
        err = np.abs(whole[:, layout.theta] - meas.x[:, layout.theta])
        exceeded = np.flatnonzero(~(err <= ol["growth_threshold_rad"]))
        ranked = sorted([w for w in windows if w["final_angle_error_rad"] is not None],
                        key=lambda w: w["final_angle_error_rad"], reverse=True)
        out.append({"maneuver": name, "role": meas.role,
                    "whole_error_exceeds_threshold_at_s": float(meas.time_s[exceeded[0]]) if len(exceeded) else None,
                    "threshold_rad": ol["growth_threshold_rad"], "worst_windows": ranked[:5],
                    "median_window_error_rad": float(np.median([w["final_angle_error_rad"] for w in ranked]))
                    if ranked else None,
                    "whole_angle_error_rad": err})
    return out


def analyse(config: dict[str, Any], fmu_path: str | Path, data_paths: dict[str, str | Path],
            segments_paths: dict[str, str | Path], best_json: str | Path | None = None,
            open_loop: bool = True) -> dict[str, Any]:
    """Run the whole diagnosis of a case and return its results (see ``diagnose`` for the files).

    Args:
        config: validated case config.
        fmu_path: the case's FMU.
        data_paths, segments_paths: maneuver name -> ingested Parquet / segments JSON.
        best_json: ``{results}/hpo/best.json`` of a trained neural FMU, or None.
        open_loop: also simulate open loop (gap before/after, error growth).
    """
    from hybridfmu.fmu import load_fmu

    settings = diagnosis_settings(config)
    fmu_parameters = dict(config.get("fmu", {}).get("parameters", {}) or {})
    model = load_fmu(fmu_path, parameters=fmu_parameters or None)
    helper = load_fmu(fmu_path, parameters=fmu_parameters or None)
    parameter_values = model.get_parameters()
    roles = {name: m["role"] for name, m in config["maneuvers"].items()}
    missing = [n for n in roles if n not in data_paths]
    if missing:
        raise ValueError(f"diagnosis: no ingested data given for maneuver(s) {missing}")
    fit_names = [n for n, r in roles.items() if r in ("train", "validation")]
    test_names = [n for n, r in roles.items() if r == "test"]
    if not fit_names:
        raise ValueError("config.maneuvers: the diagnosis needs at least one train or validation maneuver to fit on")
    measured = {name: load_maneuver(name, roles[name], data_paths[name], segments_paths.get(name), model, config)
                for name in roles}
    first = measured[fit_names[0]]
    dt_s = float(np.median(np.diff(first.time_s)))
    layout = resolve_layout(model, settings, config.get("signals"), first.x[::max(len(first.x) // 200, 1)],
                            first.u[::max(len(first.u) // 200, 1)], dt_s, parameter_values)
    prepared = {name: prepare_maneuver(m, model, layout, settings, parameter_values) for name, m in measured.items()}
    p0 = prepared[fit_names[0]]
    calibrate_constants(layout, p0.error.x, p0.error.u, model.derivatives(p0.error.x, p0.error.u), p0.error.dfdx,
                        p0.error.dfdu)
    where = equation_summary([prepared[n] for n in prepared], layout)
    regions = {}
    for group in layout.groups:
        samples, per_time = region_samples(list(prepared.values()), group, layout, settings,
                                           max(len(p0.error.kernel) // 4, 1))
        at_noise = where["groups"][group]["ratio_to_noise"] < 1.0 + SelectionSettings.from_config(
            settings.get("selection")).noise_margin
        load_max = float(max(np.max(np.abs(p.error.u[:, layout.tau_load])) for p in prepared.values())) \
            if layout.tau_load is not None else 1.0
        table = region_table(samples, settings["regions"], load_max)
        per_time.sort(key=lambda r: r["energy_share"], reverse=True)
        regions[group] = {"table": table, "unit": _group_units(group, layout),
                          "statements": ranked_statements(table, _group_units(group, layout),
                                                          settings["regions"]["top_statements"], at_noise),
                          "top_time_bins": per_time[:8]}
    which = select_effects(prepared, fit_names, layout, config, settings)
    neural = None
    neural_error = None
    if best_json is not None and Path(best_json).is_file() and settings.get("neural_fmu", True):
        try:
            neural = neural_comparison(Path(best_json), Path(fmu_path), fmu_parameters, prepared, fit_names,
                                       which["terms"], layout, which["options"])
        except Exception as err:  # the comparison is optional; its failure is reported, not fatal
            neural_error = f"{type(err).__name__}: {err}"
            LOGGER.warning("neural FMU comparison failed: %s", neural_error)
    models = {"model": model, "helper": helper}
    far = growth = None
    if open_loop and test_names:
        far = how_far(models, prepared, test_names, which["terms"], layout, which["options"], settings, neural)
        growth = error_growth(models, prepared, layout, settings)
    return {"settings": settings, "layout": layout, "prepared": prepared, "fit_names": fit_names,
            "test_names": test_names, "where": where, "regions": regions, "which": which, "neural": neural,
            "neural_error": neural_error, "how_far": far, "growth": growth, "parameter_values": parameter_values}
