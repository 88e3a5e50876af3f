"""What the trained neural FMU's ANN learned, against the diagnosed effects.

Three uses of the training package, each a thin call (adapting to a changed training API is an edit here alone):

- ``load_neural_fmu(best_json, fmu_path, parameters)``: the search's best model;
- ``learned_correction(model, x, u)``: what the ANN adds to the model's derivatives (K, n_x);
- ``simulate_neural(model, time_s, u, x0)``: whole-maneuver open loop (T, n_x).

``compare_learned_correction`` measures how much of the learned correction each chosen effect of the
same equation explains (R^2 with the diagnosis' coefficients and refitted to it).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from hybridfmu.evaluation.offset import shift_inputs
from hybridfmu.diagnosis.selection import Term, terms_in_equation


def load_neural_fmu(best_json: str | Path, fmu_path: str | Path, parameters: dict[str, float] | None) -> Any:
    """The neural FMU named by ``{results}/hpo/best.json`` around the FMU with the calibrated ``parameters``."""
    from hybridfmu.training.inference import load_trained_neural_fmu

    return load_trained_neural_fmu(best_json, fmu_path, parameters or None)


def learned_delay_s(model: Any) -> dict[str, float]:
    """The learned input delays {input: dt (s)}, FMU order."""
    return {name: float(value) for name, value in model.input_delays_s().items()}


def gate_values(model: Any) -> Any:
    return model.gate_values()


def learned_correction(model: Any, x: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Hybrid minus plain model derivatives (K, n_x) at states ``x`` (K, n_x) and (delayed) inputs ``u`` (K, n_u)."""
    import torch

    with torch.no_grad():
        xt = torch.from_numpy(np.ascontiguousarray(x, dtype=np.float64))
        ut = torch.from_numpy(np.ascontiguousarray(u, dtype=np.float64))
        return (model.derivative(xt, ut) - model.fmu(xt, ut)).numpy()


def simulate_neural(model: Any, time_s: np.ndarray, u: np.ndarray, x0: np.ndarray) -> np.ndarray:
    """Whole-maneuver open loop of a neural FMU: states (T, n_x)."""
    from hybridfmu.training.inference import simulate_neural_fmu

    return simulate_neural_fmu(model, time_s, u, x0)


def compare_learned_correction(model: Any, prepared: dict[str, Any], fit_names: list[str], terms: list[Term],
                               problem: Any) -> dict[str, Any]:
    """R^2 of the learned correction explained by each chosen effect of the same equation.

    The learned correction is evaluated along the measured trajectory at the fitting centres with the
    learned input delay; equations where it is identically zero (not corrected by the ANN) are skipped.
    """
    delay = learned_delay_s(model)
    learned, x_parts = [], []
    for name in fit_names:
        p = prepared[name]
        idx = p.fit.centres
        u = shift_inputs(p.measured.u, np.array(list(delay.values())), p.error.dt_s)[:-1][idx]
        learned.append(learned_correction(model, p.error.x[idx], u))
    c_all = np.concatenate(learned, axis=0) if learned else np.zeros((0, problem.n_x))
    corrected = [i for i in range(problem.n_x) if c_all.size and float(np.max(np.abs(c_all[:, i]))) > 0]
    rows, per_equation = [], {}
    for eq in corrected:
        c = c_all[:, eq]
        total = float(np.sum((c - c.mean()) ** 2))
        joint = []
        for term in terms_in_equation(terms, eq):
            parts = []
            for name in fit_names:
                p = prepared[name]
                regressors = np.asarray(term.effect.regressors(p.inputs, term.setting), dtype=float)
                # point values at the centres (the ANN's correction is not kernel-averaged)
                parts.append(regressors[p.fit.centres])
            design = np.concatenate(parts, axis=0)
            joint.append(design)
            fitted = design @ term.coef if design.shape[1] else np.zeros(len(c))
            r2_fit = 1.0 - float(np.sum((c - fitted) ** 2)) / total if total > 0 else None
            full = np.column_stack([design, np.ones(len(c))])
            coef, *_ = np.linalg.lstsq(full, c, rcond=None)
            r2_refit = 1.0 - float(np.sum((c - full @ coef) ** 2)) / total if total > 0 else None
            rows.append({"effect": term.effect.name, "equation": problem.state_names[eq], "r2_fitted": r2_fit,
                         "r2_refit": r2_refit})
        r2_joint = None
        if joint and total > 0:
            design = np.column_stack(joint + [np.ones((len(c), 1))])
            coef, *_ = np.linalg.lstsq(design, c, rcond=None)
            r2_joint = 1.0 - float(np.sum((c - design @ coef) ** 2)) / total
        per_equation[problem.state_names[eq]] = {"learned_correction_rms": float(np.sqrt(np.mean(c ** 2))),
                                                 "unit": problem.rate_unit(eq), "r2_joint": r2_joint}
    for eq in problem.equations:
        if eq in corrected:
            continue
        for term in terms_in_equation(terms, eq):
            rows.append({"effect": term.effect.name, "equation": problem.state_names[eq],
                         "r2_fitted": None, "r2_refit": None, "note": "the ANN does not correct this equation"})
    gates = gate_values(model)
    return {"learned_delay_s": delay, "gates": gates if isinstance(gates, (dict, list)) else str(gates),
            "equations": per_equation, "effects": rows}

