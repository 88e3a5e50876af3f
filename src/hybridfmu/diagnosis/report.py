"""Outputs of the diagnosis: ``diagnosis.json``, ``report.md`` and the figures, and the MLflow run."""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Any

import numpy as np

from hybridfmu.diagnosis import figures
from hybridfmu.io import write_json_atomic, write_text_atomic

LOGGER = logging.getLogger("hybridfmu.diagnosis")

FIGURES = {
    "equation_error.png": figures.equation_error_figure,
    "regions.png": figures.regions_figure,
    "candidates.png": figures.candidates_figure,
    "effects.png": figures.effects_figure,
}
OPEN_LOOP_FIGURES = {
    "waterfall.png": figures.waterfall_figure,
    "open_loop_test.png": figures.open_loop_figure,
    "error_growth.png": figures.growth_figure,
}


def _clean(value: Any) -> Any:
    """JSON-safe copy: NumPy to Python, non-finite floats to None."""
    if isinstance(value, dict):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    if isinstance(value, np.ndarray):
        return _clean(value.tolist())
    if isinstance(value, (np.floating, float)):
        return float(value) if math.isfinite(float(value)) else None
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value


def verdict(result: dict[str, Any]) -> str:
    """One paragraph: which equation carries the gap, what was found, how far it shrank."""
    where = result["where"]
    chosen = result["which"]["chosen"]
    groups = where["groups"]
    parts = []
    carrier = where["carrier"]
    if carrier:
        g = groups[carrier]
        parts.append(f"The {carrier} equation carries the larger gap (equation error {g['rms_residual']:.3g} "
                     f"{g['unit']} RMS, {g['ratio_to_noise']:.2f} x its noise floor).")
    if chosen:
        names = ", ".join(f"{c['rank']}. {c['effect']}" for c in chosen)
        parts.append(f"Effects named (rank order): {names}.")
    else:
        ratios = ", ".join(f"{g}: {v['ratio_to_noise']:.2f}" for g, v in groups.items())
        parts.append("No candidate effect explains a significant part of the equation error: nothing is named "
                     f"(equation error / noise floor per group: {ratios}).")
    far = result.get("how_far")
    if far:
        parts.append(f"Open-loop angle MAE on the held-out test data: {far['gap_before_rad']:.4g} rad before, "
                     f"{far['gap_after_rad']:.4g} rad with the chosen effects (factor {far['shrink_factor']:.3g}); "
                     f"in restarted windows {far['window_gap_before_rad']:.4g} -> {far['window_gap_after_rad']:.4g} rad.")
    return " ".join(parts)


def diagnosis_record(result: dict[str, Any], config: dict[str, Any]) -> dict[str, Any]:
    """The content of ``diagnosis.json``."""
    layout = result["layout"]
    which = result["which"]
    far = result.get("how_far")
    growth = result.get("growth")
    record = {
        "case": config.get("case"),
        "maneuvers": {name: m["role"] for name, m in config["maneuvers"].items()},
        "fit_maneuvers": result["fit_names"], "test_maneuvers": result["test_names"],
        "method": {
            "equation_error": "measured one-sample change minus the model's (RK4 step for the currents, trapezoid "
                              "for the other states) with inputs held, averaged with a Hann kernel",
            "kernel_s": result["settings"]["kernel_s"], "speed_source": result["settings"]["speed_source"],
            "input_lag_compensation_s": result["settings"].get("input_lag_compensation_s", {}),
            "selection": result["settings"].get("selection", {}),
        },
        "layout": {"state_names": layout.state_names, "input_names": layout.input_names,
                   "groups": {g: [layout.state_names[i] for i in rows] for g, rows in layout.groups.items()},
                   "pole_pairs": layout.pole_pairs, "inertia_kg_m2": layout.inertia_kg_m2,
                   "calibrated_constants": layout.constants},
        "verdict": verdict(result),
        "where": {
            "equations": result["where"],
            "regions": {g: {k: v for k, v in r.items()} for g, r in result["regions"].items()},
            "open_loop_growth": [{k: v for k, v in item.items() if k != "whole_angle_error_rad"}
                                 for item in (growth or [])],
        },
        "which": {
            "found_effects": [c["effect"] for c in which["chosen"]],
            "chosen": which["chosen"], "groups": which["groups"], "skipped_candidates": which["skipped"],
        },
        "neural_fmu": None if result.get("neural") is None else
        {k: v for k, v in result["neural"].items() if k != "model"},
        "neural_fmu_error": result.get("neural_error"),
        "how_far": None if far is None else {k: v for k, v in far.items() if k != "trajectories"},
    }
    return _clean(record)


def _fmt(value: Any, digits: int = 4) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:.{digits}g}"
    return str(value)


def report_markdown(record: dict[str, Any], figure_names: list[str]) -> str:
    """``report.md``: the diagnosis in words, tables and figures."""
    lines = [f"# Diagnosis of the sim-to-real gap: case `{record['case']}`", "", record["verdict"], ""]
    eq = record["where"]["equations"]
    lines += ["## Where", "", "### Equation error per state", "",
              "Kernel-averaged equation error (measured minus model) at the fitting centres of all maneuvers; "
              "the noise floor is the same quantity computed from a realisation of the measurement noise "
              "on the states (input noise such as the supply-voltage samples is not in it).", "",
              "| state | RMS residual | noise floor | ratio | spread of derivative | normalised residual | "
              "normalised excess |", "|---|---|---|---|---|---|---|"]
    for name, s in eq["states"].items():
        lines.append(f"| {name} | {_fmt(s['rms_residual'])} | {_fmt(s['noise_floor'])} | {_fmt(s['ratio_to_noise'], 3)} | "
                     f"{_fmt(s['derivative_spread'])} | {_fmt(s['normalised_residual'], 3)} | "
                     f"{_fmt(s['normalised_excess'], 3)} |")
    lines += ["", "| equation group | RMS residual | noise floor | ratio |", "|---|---|---|---|"]
    for group, g in eq["groups"].items():
        lines.append(f"| {group} ({', '.join(g['states'])}) | {_fmt(g['rms_residual'])} {g['unit']} | "
                     f"{_fmt(g['noise_floor'])} {g['unit']} | {_fmt(g['ratio_to_noise'], 3)} |")
    lines += ["", f"The gap is carried mainly by the **{eq['carrier']}** equation.", "",
              "### Operating regions", ""]
    for group, info in record["where"]["regions"].items():
        lines.append(f"**{group} equation** ({info['unit']}):")
        lines += [f"- {s}" for s in info["statements"]]
        lines.append("")
        top = info.get("top_time_bins", [])[:4]
        if top:
            lines.append("Time spans with the most residual energy: " + "; ".join(
                f"{t['maneuver']} {t['t_start_s']:.2f}-{t['t_end_s']:.2f} s ({100 * t['energy_share']:.0f} %, "
                f"{_fmt(t['ratio_to_noise'], 3)} x noise)" for t in top) + ".")
            lines.append("")
    growth = record["where"]["open_loop_growth"]
    if growth:
        lines += ["### Over time: where the open-loop error grows", "",
                  "| maneuver | role | whole-maneuver error exceeds threshold at | worst restarted windows "
                  "(final angle error) |", "|---|---|---|---|"]
        for item in growth:
            worst = "; ".join(f"{w['t_start_s']:.1f}-{w['t_end_s']:.1f} s: {_fmt(w['final_angle_error_rad'], 3)} rad"
                              for w in item["worst_windows"][:3])
            at = "never" if item["whole_error_exceeds_threshold_at_s"] is None else \
                f"{item['whole_error_exceeds_threshold_at_s']:.3f} s"
            lines.append(f"| {item['maneuver']} | {item['role']} | {at} ({_fmt(item['threshold_rad'])} rad) | {worst} |")
        lines.append("")
    which = record["which"]
    lines += ["## Which", ""]
    if not which["chosen"]:
        lines += ["No candidate effect is named: none removes enough of the equation error "
                  "(see the candidate table below).", ""]
    for c in which["chosen"]:
        lines += [f"### {c['rank']}. `{c['effect']}` ({c['group']} equation)", "",
                  f"{c['description']}: `{c['equation']}`. Drop-one score {c['score']:.4g} "
                  "(increase of the residual sum of squares without it, in residual variances).", "",
                  "| parameter | value | SE (regression) | SE (bootstrap over segments) | unit | spread train/validation |",
                  "|---|---|---|---|---|---|"]
        for p in c["parameters"]:
            stab = c["stability"].get(p["name"])
            spread = f"{100 * stab['relative_spread']:.1f} %" if stab else "-"
            lines.append(f"| {p['name']} | {_fmt(p['value'], 5)} | {_fmt(p['se'], 3)} | {_fmt(p['se_bootstrap'], 3)} | "
                         f"{p['unit']} | {spread} |")
        lines.append("")
    lines += ["### Candidates and selection steps", ""]
    for group, info in which["groups"].items():
        lines.append(f"**{group}** ({info['n_samples']} samples, {100 * info['explained_share']:.1f} % of the residual "
                     f"explained by the chosen effects; chosen per fitting maneuver alone: "
                     f"{info['selection_per_maneuver'] or '-'})")
        lines.append("")
        for k, step in enumerate(info["steps"], start=1):
            lines.append(f"Step {k}: {step['reason']}.")
            lines += ["", "| candidate | setting | residual removed | BIC |", "|---|---|---|---|"]
            for cand in step["candidates"]:
                setting = ", ".join(f"{key}={_fmt(v, 4)}" for key, v in cand["setting"].items()) or "-"
                lines.append(f"| {cand['effect']} | {setting} | {100 * cand['relative_improvement']:.2f} % | "
                             f"{cand['bic']:.1f} |")
            lines.append("")
    if which["skipped_candidates"]:
        lines += ["Skipped candidates: " + "; ".join(f"{k} ({v})" for k, v in which["skipped_candidates"].items()), ""]
    nn = record.get("neural_fmu")
    if nn:
        lines += ["### Compared with the trained neural FMU", "",
                  f"Learned input delay {nn['learned_delay_s']:.3g} s, gates {nn['gates']}; RMS of the learned "
                  f"speed-equation correction {nn['learned_correction_rms']:.3g} {nn['unit']}. Share of it each "
                  f"chosen effect explains (R^2 with the diagnosis's parameters / refitted to it):", "",
                  "| effect | R^2 (fitted) | R^2 (refitted) |", "|---|---|---|"]
        for row in nn["effects"]:
            lines.append(f"| {row['effect']} | {_fmt(row['r2_fitted'], 3)} | {_fmt(row['r2_refit'], 3)} |")
        lines += ["", f"All chosen mechanical effects together (refitted): R^2 = {_fmt(nn['r2_joint'], 3)}.", ""]
    elif record.get("neural_fmu_error"):
        lines += [f"The comparison with the neural FMU failed: {record['neural_fmu_error']}", ""]
    else:
        lines += ["No trained neural FMU was available for comparison.", ""]
    far = record.get("how_far")
    if far:
        lines += ["## How far", "",
                  "Open loop on the held-out test maneuver(s) (no fit saw them), from the measured initial state, "
                  "driven by the logged duties; the chosen effects are added one at a time in rank order as explicit "
                  "correction terms. The motor is driven by duties computed from the measured angle, so a simulated "
                  "angle that drifts away loses synchronism and the whole-maneuver error explodes; the windowed "
                  "errors (every window restarted from the measured state) show the local accuracy without that.", "",
                  "| model | angle MAE (rad) | angle MSE (rad^2) | speed MAE (rad/s) | speed MSE (rad^2/s^2) | "
                  "windowed angle MAE (rad) | windowed speed MAE (rad/s) |", "|---|---|---|---|---|---|---|"]
        for s in far["steps"]:
            lines.append(f"| {s['model']} | {_fmt(s['angle_mae_rad'])} | {_fmt(s['angle_mse_rad2'])} | "
                         f"{_fmt(s['speed_mae_rad_s'])} | {_fmt(s['speed_mse_rad2_s2'])} | "
                         f"{_fmt(s['window_angle_mae_rad'])} | {_fmt(s['window_speed_mae_rad_s'])} |")
        lines += ["", f"Gap (whole-maneuver angle MAE): {_fmt(far['gap_before_rad'])} rad -> {_fmt(far['gap_after_rad'])} "
                      f"rad, factor {_fmt(far['shrink_factor'], 3)}.", ""]
    lines += ["## Figures", ""] + [f"![{name}]({name})" for name in figure_names] + [""]
    lines += ["## Notes", "",
              "- The diagnosis reads only the FMU, the ingested logs and their segments (never the bench's ground "
              "truth).",
              "- Speeds are differentiated from the measured angle when `speed_source` is `angle` (the logged speed of "
              "an observer lags during acceleration); known sensor lags in `input_lag_compensation_s` are undone "
              "before everything (also in the open-loop simulations).",
              "- Standard errors: regression ones assume independent samples one kernel length apart; bootstrap ones "
              "resample segment blocks with the nonlinear settings fixed.", ""]
    return "\n".join(lines)


def write_outputs(result: dict[str, Any], config: dict[str, Any], out_dir: str | Path) -> dict[str, Any]:
    """Write ``diagnosis.json``, ``report.md`` and the figures to ``out_dir``; return the record and paths."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    dpi = int(result["settings"].get("figures_dpi", 120))
    record = diagnosis_record(result, config)
    makers = dict(FIGURES)
    if result.get("how_far"):
        makers.update(OPEN_LOOP_FIGURES)
    written = []
    for name, maker in makers.items():
        written.append(maker(result, out_dir / name, dpi))
    write_json_atomic(out_dir / "diagnosis.json", record)
    write_text_atomic(out_dir / "report.md", report_markdown(record, [p.name for p in written]))
    return {"record": record, "figures": written, "json": out_dir / "diagnosis.json", "report": out_dir / "report.md"}


def log_to_mlflow(record: dict[str, Any], paths: dict[str, Any], config: dict[str, Any]) -> str:
    """Log the diagnosis as an MLflow run (tag ``hybridfmu.role = diagnosis``); return the run id."""
    from hybridfmu.tracking import Tracker, experiment_name, tracking_uri

    uri = tracking_uri(config.get("mlflow"), Path(config.get("results_dir", "results")).resolve())
    tracker = Tracker(uri)
    experiment_id = tracker.experiment_id(experiment_name(config.get("mlflow"), config["case"]))
    run_id = tracker.call("create_run", experiment_id, tags={"hybridfmu.role": "diagnosis", "case": config["case"]},
                          run_name="diagnosis").info.run_id
    try:
        metrics = []
        for group, g in record["where"]["equations"]["groups"].items():
            metrics.append((f"where/{group}/rms_residual", g["rms_residual"], 0))
            metrics.append((f"where/{group}/ratio_to_noise", g["ratio_to_noise"], 0))
        far = record.get("how_far")
        if far:
            for step_index, step in enumerate(far["steps"]):
                for key in ("angle_mae_rad", "angle_mse_rad2", "speed_mae_rad_s", "speed_mse_rad2_s2",
                            "window_angle_mae_rad"):
                    if step.get(key) is not None:
                        metrics.append((f"how_far/{key}", step[key], step_index))
            for key in ("gap_before_rad", "gap_after_rad", "shrink_factor"):
                if far.get(key) is not None:
                    metrics.append((f"gap/{key}", far[key], 0))
        params = {"found_effects": ",".join(record["which"]["found_effects"]) or "none"}
        for c in record["which"]["chosen"]:
            for p in c["parameters"]:
                params[f"{c['effect']}.{p['name']}"] = f"{p['value']:.6g}"
        tracker.log(run_id, params=params, metrics=[m for m in metrics if m[1] is not None])
        for path in [paths["json"], paths["report"], *paths["figures"]]:
            tracker.log_artifact(run_id, path, artifact_path="diagnosis")
    except Exception:
        tracker.set_status(run_id, "FAILED")
        raise
    tracker.set_status(run_id, "FINISHED")
    LOGGER.info("MLflow diagnosis run %s (%s)", run_id, uri)
    return run_id


def diagnose(config: dict[str, Any], fmu_path: str | Path, data_paths: dict[str, str | Path],
             segments_paths: dict[str, str | Path], out_dir: str | Path, best_json: str | Path | None = None,
             mlflow: bool = True) -> dict[str, Any]:
    """Diagnose the sim-to-real gap of a case; write ``diagnosis.json``, ``report.md`` and figures.

    Args:
        config: validated case config (sections ``diagnosis``, ``signals``, ``maneuvers``, ``fmu``, ``mlflow``).
        fmu_path: the case's FMU.
        data_paths, segments_paths: maneuver -> ingested Parquet / segments JSON (all maneuvers of the case).
        out_dir: ``{results}/diagnosis``.
        best_json: ``{results}/hpo/best.json`` when a neural FMU was trained (optional).
        mlflow: log the run to MLflow.
    Returns:
        The ``diagnosis.json`` record.
    """
    from hybridfmu.diagnosis.run import analyse

    result = analyse(config, fmu_path, data_paths, segments_paths, best_json)
    paths = write_outputs(result, config, out_dir)
    if mlflow:
        paths["record"]["mlflow_run_id"] = log_to_mlflow(paths["record"], paths, config)
        write_json_atomic(paths["json"], paths["record"])
    LOGGER.info("diagnosis: %s", paths["record"]["verdict"])
    return paths["record"]
