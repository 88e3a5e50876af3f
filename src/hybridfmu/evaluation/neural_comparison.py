"""Rule compare_neural_fmu: the trained neural FMU beside the diagnosis (``neural_fmu.json``, ``neural_fmu.md``).

Two questions, answered once the search has its best model and the diagnosis its effects (the diagnosis itself
never waits for the search):

- what the ANN learned: the learned correction of each equation it corrects, along the measured trajectories of
  the fitting maneuvers, and how much of it each diagnosed effect explains (R^2 with the diagnosis' coefficients
  and refitted to it, :func:`hybridfmu.evaluation.learned_correction.compare_learned_correction`);
- how far the neural FMU gets on the diagnosis' test maneuvers in open loop, beside the diagnosis' own held-out
  check (the FMU and the FMU + effects, read from ``diagnosis.json``), in the same normalised gap.

The effects are those of the diagnosed model (``diagnosed_model.pkl``), the model the held-out check ends with.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from hybridfmu.diagnosis.corrected_model import simulator_for, target_errors
from hybridfmu.diagnosis.export import load_diagnosed
from hybridfmu.evaluation.learned_correction import compare_learned_correction, load_neural_fmu, simulate_neural
from hybridfmu.diagnosis.report import format_number, json_safe, table_cell
from hybridfmu.diagnosis.inputs import load_inputs
from hybridfmu.diagnosis.open_loop import mean_errors, reference_states
from hybridfmu.diagnosis.run import prepare_all
from hybridfmu.io import read_json, write_json_atomic, write_text_atomic
from hybridfmu.model.delay import format_delay

LOGGER = logging.getLogger("hybridfmu.diagnosis")

#: Files the rule writes in the diagnosis folder.
COMPARISON_JSON = "neural_fmu.json"
COMPARISON_MD = "neural_fmu.md"


def compare_neural_fmu(config: dict[str, Any], fmu_path: str | Path, data_paths: dict[str, str | Path],
                       segments_paths: dict[str, str | Path], best_json: str | Path, diagnosed_path: str | Path,
                       diagnosis_json: str | Path, out_dir: str | Path,
                       calibration_path: str | Path | None = None, mlflow: bool = True) -> dict[str, Any]:
    """Compare the search's best neural FMU with the diagnosis; write ``neural_fmu.json`` and ``neural_fmu.md``.

    Args:
        config: validated case config (as for :func:`hybridfmu.diagnosis.report.diagnose`).
        fmu_path: the case's FMU.
        data_paths, segments_paths: maneuver -> ingested Parquet / segments JSON (the diagnosis' maneuvers).
        best_json: ``{results}/hpo/best.json``.
        diagnosed_path: ``{results}/diagnosis/diagnosed_model.pkl``.
        diagnosis_json: ``{results}/diagnosis/diagnosis.json`` (its held-out check is shown beside).
        out_dir: ``{results}/diagnosis``.
        calibration_path: ``{results}/calibration/calibration.json``, or None.
        mlflow: log both files and the neural FMU's open-loop gap to the diagnosis' MLflow run (its id in
            ``diagnosis.json``; nothing is logged when the diagnosis logged no run).
    Returns:
        The ``neural_fmu.json`` record.
    """
    case = load_inputs(config, fmu_path, data_paths, segments_paths, calibration_path)
    prepared, fit_names, test_names = prepare_all(case.problem, case.model, case.measured,
                                                  simulator_for(case.model))
    diagnosed = load_diagnosed(diagnosed_path)
    model = load_neural_fmu(best_json, fmu_path, case.parameters)
    record: dict[str, Any] = {"best": str(best_json), "effects": list(diagnosed.effects),
                              "fit_maneuvers": fit_names, "test_maneuvers": test_names}
    record["correction"] = compare_learned_correction(model, prepared, fit_names, diagnosed.terms, case.problem)
    per = {}
    for name in test_names:
        meas = prepared[name].measured
        starts = prepared[name].starts
        try:
            states = simulate_neural(model, meas.time_s, meas.u, starts[0])
        except Exception as err:  # reported, not fatal: the correction above stands on its own
            LOGGER.warning("neural FMU open loop on %s failed: %s", name, err)
            states = np.full_like(meas.x, np.nan)
        per[name] = target_errors(states, reference_states(meas, starts, case.problem), case.problem)
        LOGGER.info("open loop neural FMU on %s: normalised gap %.4g", name, per[name]["gap"])
    record["open_loop"] = {"per_maneuver": per, **mean_errors(per)} if per else None
    diagnosis = read_json(diagnosis_json) or {}
    far = diagnosis.get("how_far")
    record["diagnosis_open_loop"] = None if not far else {
        "FMU": far["before"], "FMU + effects": far["after"]}
    record = json_safe(record)
    out_dir = Path(out_dir)
    write_json_atomic(out_dir / COMPARISON_JSON, record)
    write_text_atomic(out_dir / COMPARISON_MD, comparison_markdown(record, case.problem.target_weights))
    if mlflow and diagnosis.get("mlflow_run_id"):
        log_to_diagnosis_run(record, [out_dir / COMPARISON_JSON, out_dir / COMPARISON_MD], config,
                             diagnosis["mlflow_run_id"])
    return record


def log_to_diagnosis_run(record: dict[str, Any], paths: list[Path], config: dict[str, Any], run_id: str) -> None:
    """Add the comparison to the diagnosis' MLflow run: the files under ``diagnosis/``, the neural FMU's mean
    open-loop errors as ``neural_fmu/<error>``."""
    from hybridfmu.tracking import Tracker, tracking_uri

    tracker = Tracker(tracking_uri(config.get("mlflow"), Path(config.get("results_dir", "results")).resolve()))
    loop = record.get("open_loop") or {}
    metrics = [(f"neural_fmu/{key}", value, 0) for key, value in loop.items()
               if key != "per_maneuver" and isinstance(value, (int, float))]
    tracker.log(run_id, params={}, metrics=metrics)
    for path in paths:
        tracker.log_artifact(run_id, path, artifact_path="diagnosis")
    LOGGER.info("neural FMU comparison logged to the MLflow diagnosis run %s", run_id)


def delays_text(delays: dict[str, float]) -> str:
    """``{input: s}`` with the inputs of one value together: 'u1, u2 28.14 µs; u3 0.00 µs'."""
    by_value: dict[float, list[str]] = {}
    for name, value in delays.items():
        by_value.setdefault(float(value), []).append(name)
    return "; ".join(f"{', '.join(names)} {format_delay(value)}" for value, names in by_value.items())


def gates_text(gates: Any) -> str:
    """``x: g_F 0.95, g_A 0.242``: the gates per corrected state (a non-dict value as text)."""
    if not isinstance(gates, dict):
        return str(gates)
    return "; ".join(f"{state}: " + (", ".join(f"{name} {format_number(v, 3)}" for name, v in values.items())
                                     if isinstance(values, dict) else format_number(values, 3))
                     for state, values in gates.items())


def comparison_markdown(record: dict[str, Any], targets: dict[str, float]) -> str:
    """``neural_fmu.md``: the learned correction against the diagnosed effects and the open-loop gaps."""
    correction = record["correction"]
    lines = ["# The trained neural FMU beside the diagnosis", "",
             f"Best model: `{record['best']}`; diagnosed effects: "
             f"{', '.join(table_cell(e) for e in record['effects']) or 'none'}.", "",
             "## What the ANN learned", "",
             f"Learned input delays {delays_text(correction['learned_delay_s'])}, gates "
             f"{gates_text(correction['gates'])}. The learned correction per equation along the measured trajectories "
             f"of {', '.join(record['fit_maneuvers'])}: "
             + ("; ".join(f"d{k}/dt: RMS {format_number(v['learned_correction_rms'], 3)} {v['unit']}, joint R^2 of "
                          f"the diagnosed effects {format_number(v['r2_joint'], 3)}"
                          for k, v in correction["equations"].items()) or "none (the ANN corrects no equation)")
             + ".", "",
             "| effect | equation | R^2 (diagnosed coefficients) | R^2 (refitted) | note |", "|---|---|---|---|---|"]
    for row in correction["effects"]:
        lines.append(f"| {table_cell(row['effect'])} | d{row['equation']}/dt | {format_number(row['r2_fitted'], 3)} | "
                     f"{format_number(row['r2_refit'], 3)} | {row.get('note', '')} |")
    lines += ["", "An R^2 near 1 says the ANN learned what the effect describes; near 0 (or negative with the "
              "diagnosed coefficients) that it learned something else, or a different size of it.", ""]
    loop = record.get("open_loop")
    if loop:
        lines += ["## Open loop on the diagnosis' test maneuvers", "",
                  f"Mean over {', '.join(record['test_maneuvers'])}; gap: the target-weighted MAE over each target's "
                  f"spread ({', '.join(targets)}), as in the diagnosis' held-out check.", ""]
        keys = ["gap"] + sorted(k for k in loop if k.endswith("_mae"))
        lines += ["| model | " + " | ".join(keys) + " |", "|---|" + "---|" * len(keys)]
        rows = dict(record.get("diagnosis_open_loop") or {})
        rows["neural FMU"] = loop
        for label, values in rows.items():
            lines.append(f"| {label} | " + " | ".join(format_number(values.get(k), 4) for k in keys) + " |")
        lines.append("")
    return "\n".join(lines)
