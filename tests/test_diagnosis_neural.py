"""Comparison with a hybrid model's learned correction: an effect that is exactly what the model
learned explains it (R^2 near 1), an unrelated one does not, electrical effects are not compared."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from hybridfmu.diagnosis.effects import EFFECTS, effect_options
from hybridfmu.diagnosis.layout import resolve_layout
from hybridfmu.diagnosis.prepare import MeasuredManeuver, prepare_maneuver
from hybridfmu.diagnosis.run import learned_correction_r2
from hybridfmu.diagnosis.selection import Term
from hybridfmu.diagnosis.synthetic import PmsmReference
from test_diagnosis_residual import exact_trajectory

FRICTION_NM = 0.03


class LearnedFriction(torch.nn.Module):
    """A hybrid model whose correction of the speed equation is Coulomb friction (what an ANN may learn)."""

    def __init__(self, model: PmsmReference, inertia: float) -> None:
        super().__init__()
        self.model, self.inertia = model, inertia

    def fmu(self, x: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        return torch.from_numpy(self.model.derivatives(x.numpy(), u.numpy()))

    def derivative(self, x: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        out = self.fmu(x, u).clone()
        out[:, 3] -= FRICTION_NM * torch.tanh(x[:, 3] / 0.5) / self.inertia
        return out

    def delay_s(self) -> float:
        return 0.0

    def gate_values(self) -> dict[str, dict[str, float]]:
        return {"omega": {"g_F": 1.0, "g_A": 1.0}}


def test_learned_correction_is_explained_by_the_matching_effect():
    model = PmsmReference()
    time_s, x, u = exact_trajectory(model, n=3000, substeps=5, seed=2)
    measured = MeasuredManeuver("train", "train", time_s, x, u, [[0.0, float(time_s[-1])]])
    settings = {"kernel_s": 0.004, "smoothing_s": 0.002, "standstill_rad_s": 0.0, "end_stop_margin_rad": 0.0,
                "bootstrap_block_s": 0.1, "seed": 0, "speed_source": "measured"}
    layout = resolve_layout(model, {}, None, x[:50], u[:50], 1e-4, model.parameters)
    prepared = {"train": prepare_maneuver(measured, model, layout, settings, model.parameters)}
    assert layout.inertia_kg_m2 == pytest.approx(2e-4)
    options = effect_options({})
    terms = [Term(EFFECTS["coulomb_friction"], {"stribeck_velocity_rad_s": 0.0}, np.array([FRICTION_NM])),
             Term(EFFECTS["cogging"], {"order": 24.0, "harmonics": 1.0}, np.array([0.01, 0.0])),
             Term(EFFECTS["resistance_error"], {}, np.array([0.05]))]
    result = learned_correction_r2(LearnedFriction(model, layout.inertia_kg_m2), prepared, ["train"], terms, layout,
                                   options)
    rows = {row["effect"]: row for row in result["effects"]}
    assert rows["coulomb_friction"]["r2_fitted"] > 0.95
    assert rows["coulomb_friction"]["r2_refit"] >= rows["coulomb_friction"]["r2_fitted"] - 1e-9
    assert rows["cogging"]["r2_refit"] < 0.2
    assert rows["resistance_error"]["r2_fitted"] is None and "electrical" in rows["resistance_error"]["note"]
    assert result["r2_joint"] > 0.95
    assert result["learned_correction_rms"] == pytest.approx(FRICTION_NM, rel=0.2)
