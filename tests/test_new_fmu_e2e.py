"""An FMU the pipeline has never seen, driven through the config alone, end to end through Snakemake.

The test builds a small C model (a mass on a spring with viscous damping, one force input; sources in
tests/fixtures/mass_spring/, on the project's FMU core) into an FMU, writes CSV logs of a "real"
mass-spring whose physics the FMU lacks (Coulomb friction) with the column names and units a
user's logger would choose, writes a case config for them, and runs the whole workflow
(calibration, ingest, segments, baseline, Hyperband, evaluation, report, diagnosis). No code of the
package knows this model.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from hybridfmu.fmu.build import build_fmu_from_description

REPO = Path(__file__).resolve().parents[1]
FIXTURE = REPO / "tests" / "fixtures" / "mass_spring" / "modelDescription.xml"

pytestmark = pytest.mark.slow

#: The FMU's nominal parameters (modelDescription.xml start values) and the "real" system's.
MASS_KG, STIFFNESS_N_M, DAMPING_N_S_M = 1.0, 40.0, 0.8
COULOMB_N = 0.8            # unmodelled: Coulomb friction, smoothed over 5 mm/s
SMOOTHING_M_S = 0.005
RATE_HZ = 500.0


def true_acceleration(x_m: np.ndarray, v_m_s: np.ndarray, force_n: np.ndarray) -> np.ndarray:
    """Acceleration (m/s^2) of the "real" mass-spring: the FMU's equation plus Coulomb friction."""
    friction_n = COULOMB_N * np.tanh(v_m_s / SMOOTHING_M_S)
    return (force_n - STIFFNESS_N_M * x_m - DAMPING_N_S_M * v_m_s - friction_n) / MASS_KG


def force_profile(rng: np.random.Generator, time_s: np.ndarray) -> np.ndarray:
    """A logged force (N): rest, then a sum of random sines and a few steps, then rest."""
    duration_s = time_s[-1]
    force = np.zeros_like(time_s)
    for _ in range(4):
        frequency_hz = rng.uniform(0.3, 3.0)
        force += rng.uniform(1.0, 3.0) * np.sin(2 * np.pi * frequency_hz * time_s + rng.uniform(0, 2 * np.pi))
    for start_s in rng.uniform(0.2 * duration_s, 0.8 * duration_s, size=3):
        force += rng.uniform(-2.0, 2.0) * (time_s >= start_s)
    active = (time_s > 0.1 * duration_s) & (time_s < 0.9 * duration_s)
    return np.where(active, force, 0.0)


def simulate_log(rng: np.random.Generator, duration_s: float) -> pd.DataFrame:
    """The "measured" log: RK4 at 10x the log rate, sampled at RATE_HZ, sensor noise added."""
    substeps = 10
    dt_s = 1.0 / (RATE_HZ * substeps)
    time_s = np.arange(int(duration_s * RATE_HZ) + 1) / RATE_HZ
    force = force_profile(rng, time_s)
    x, v = 0.0, 0.0
    positions, velocities = [], []
    for k in range(time_s.size):
        positions.append(x)
        velocities.append(v)
        f = np.array(force[k])
        for _ in range(substeps):
            def rhs(state):
                return np.array([state[1], true_acceleration(np.array(state[0]), np.array(state[1]), f)])
            s = np.array([x, v])
            k1 = rhs(s)
            k2 = rhs(s + 0.5 * dt_s * k1)
            k3 = rhs(s + 0.5 * dt_s * k2)
            k4 = rhs(s + dt_s * k3)
            x, v = s + dt_s * (k1 + 2 * k2 + 2 * k3 + k4) / 6.0
    return pd.DataFrame({
        "time_ms": time_s * 1e3,
        "force_n": force,
        "position_mm": np.asarray(positions) * 1e3 + rng.normal(0.0, 0.01, time_s.size),
        "velocity_mps": np.asarray(velocities) + rng.normal(0.0, 0.002, time_s.size),
    })
