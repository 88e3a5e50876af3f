"""Where the equation error lies: its energy over operating regions and over time.

Every sample of the kernel-averaged equation error is assigned to regions of several families
(speed band, sign of the acceleration, load band, near a direction reversal, angle within a
revolution, near an end stop, standstill). For each region the share of the residual energy
(and of the energy above the noise floor) is compared with the share of time spent there; the
regions where the energy concentrates most are ranked and stated in words. Over time, the
residual energy per time bin and the growth of the open-loop error per restarted window show
when the model departs from the data.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

DEFAULT_REGION_SETTINGS: dict[str, Any] = {
    "speed_bands_rad_s": [1.0, 5.0, 20.0, 100.0],
    "acceleration_threshold_rad_s2": 200.0,
    "load_bands_relative": [0.02, 0.25, 0.5],
    "reversal_window_s": 0.02,
    "reversal_speed_rad_s": 2.0,
    "angle_bins": 8,
    "time_bin_s": 0.25,
    "top_statements": 6,
}


@dataclass
class RegionSamples:
    """Per-sample features and residual energies of one equation group (pooled over maneuvers).

    Attributes:
        energy: (K,) squared residual (group units^2, e.g. (N m)^2 for the mechanical group).
        noise_energy: (K,) expected squared residual from noise alone.
        signed: (K,) signed residual (mechanical: torque N m; electrical: |r| in A/s).
        features: name -> (K,) values (omega_rad_s, accel_rad_s2, tau_load_nm, theta_rad,
            reversal (bool), near_stop (bool), standstill (bool)).
    """

    energy: np.ndarray
    noise_energy: np.ndarray
    signed: np.ndarray
    features: dict[str, np.ndarray]


def _band_labels(edges: list[float], unit: str, name: str) -> list[str]:
    labels = [f"{name} < {edges[0]:g} {unit}"]
    labels += [f"{a:g} <= {name} < {b:g} {unit}" for a, b in zip(edges[:-1], edges[1:])]
    labels.append(f"{name} >= {edges[-1]:g} {unit}")
    return labels


def region_assignments(features: dict[str, np.ndarray], settings: dict[str, Any],
                       load_max_nm: float) -> dict[str, tuple[list[str], np.ndarray]]:
    """Region family -> (labels, (K,) index of the label of every sample)."""
    out: dict[str, tuple[list[str], np.ndarray]] = {}
    speed_edges = sorted(float(v) for v in settings["speed_bands_rad_s"])
    out["speed"] = (_band_labels(speed_edges, "rad/s", "|omega|"),
                    np.searchsorted(speed_edges, np.abs(features["omega_rad_s"]), side="right"))
    a_thr = float(settings["acceleration_threshold_rad_s2"])
    accel = features["accel_rad_s2"]
    out["acceleration"] = ([f"decelerating (d|omega|/dt < -{a_thr:g} rad/s^2)", "steady speed",
                            f"accelerating (d|omega|/dt > {a_thr:g} rad/s^2)"],
                           np.where(accel * np.sign(features["omega_rad_s"]) > a_thr, 2,
                                    np.where(accel * np.sign(features["omega_rad_s"]) < -a_thr, 0, 1)))
    load_edges = [float(v) * max(load_max_nm, 1e-12) for v in settings["load_bands_relative"]]
    out["load"] = (_band_labels([round(v, 4) for v in load_edges], "N m", "|tau_load|"),
                   np.searchsorted(load_edges, np.abs(features["tau_load_nm"]), side="right"))
    out["direction"] = (["moving towards positive theta", "moving towards negative theta"],
                        (features["omega_rad_s"] < 0).astype(int))
    out["reversal"] = (["away from direction reversals",
                        f"within {settings['reversal_window_s']:g} s of a direction reversal"],
                       features["reversal"].astype(int))
    n_bins = int(settings["angle_bins"])
    angle = np.mod(features["theta_rad"], 2.0 * math.pi)
    width_deg = 360.0 / n_bins
    out["angle"] = ([f"angle within a revolution {k * width_deg:g}-{(k + 1) * width_deg:g} deg"
                     for k in range(n_bins)],
                    np.minimum((angle / (2.0 * math.pi) * n_bins).astype(int), n_bins - 1))
    out["end_stop"] = (["away from the end stops", "near an end stop"], features["near_stop"].astype(int))
    out["standstill"] = (["rotor moving", "rotor at standstill"], features["standstill"].astype(int))
    return out


def region_table(samples: RegionSamples, settings: dict[str, Any], load_max_nm: float) -> list[dict[str, Any]]:
    """One row per region: time share, energy share, share of the energy above noise, mean signed residual."""
    total_energy = float(np.sum(samples.energy))
    rows = []
    for family, (labels, index) in region_assignments(samples.features, settings, load_max_nm).items():
        region_excess = []
        for k, label in enumerate(labels):
            inside = index == k
            if not inside.any():
                continue
            energy = float(np.sum(samples.energy[inside]))
            above = max(energy - float(np.sum(samples.noise_energy[inside])), 0.0)
            region_excess.append(above)
            rows.append({
                "family": family, "region": label, "time_share": float(inside.mean()),
                "energy_share": energy / total_energy if total_energy > 0 else 0.0,
                "excess_energy": above, "mean_residual": float(np.mean(samples.signed[inside])),
                "mean_residual_along_motion": float(np.mean(samples.signed[inside]
                                                            * np.sign(samples.features["omega_rad_s"][inside]))),
                "samples": int(inside.sum()),
            })
        family_excess = sum(region_excess)
        for row in rows:
            if row["family"] == family:
                row["excess_share"] = row["excess_energy"] / family_excess if family_excess > 0 else 0.0
    for row in rows:
        row.pop("excess_energy")
        row["concentration"] = row["energy_share"] / row["time_share"] if row["time_share"] > 0 else 0.0
    return rows


def ranked_statements(rows: list[dict[str, Any]], unit: str, top: int, at_noise: bool) -> list[str]:
    """Sentences for the regions where the residual energy concentrates most."""
    if at_noise:
        return ["the residual is at the noise level: no region stands out"]
    candidates = [r for r in rows if r["time_share"] >= 0.01 and r["time_share"] < 0.99]
    candidates.sort(key=lambda r: r["excess_share"] - r["time_share"], reverse=True)
    out = []
    for row in candidates[:top]:
        out.append(f"{100 * row['excess_share']:.0f} % of the residual energy above noise "
                   f"({100 * row['energy_share']:.0f} % of all) lies at {row['region']}, "
                   f"{100 * row['time_share']:.0f} % of the time (mean residual {row['mean_residual']:+.3g} {unit}, "
                   f"{row['mean_residual_along_motion']:+.3g} {unit} along the motion)")
    return out


def reversal_mask(omega_rad_s: np.ndarray, dt_s: float, speed_rad_s: float, window_s: float) -> np.ndarray:
    """(K,) bool: within ``window_s`` of a direction reversal (speed crossing from > +v to < -v or back)."""
    state = np.zeros(len(omega_rad_s), dtype=int)
    state[omega_rad_s > speed_rad_s] = 1
    state[omega_rad_s < -speed_rad_s] = -1
    nonzero = np.flatnonzero(state)
    mask = np.zeros(len(omega_rad_s), dtype=bool)
    if len(nonzero) < 2:
        return mask
    changes = nonzero[1:][state[nonzero[1:]] != state[nonzero[:-1]]]
    previous = nonzero[:-1][state[nonzero[1:]] != state[nonzero[:-1]]]
    half = int(round(window_s / dt_s))
    for start, end in zip(previous, changes):
        mask[max(start - half, 0):min(end + half + 1, len(mask))] = True
    return mask


def time_bins(time_s: np.ndarray, energy: np.ndarray, noise_energy: np.ndarray, bin_s: float) -> list[dict[str, Any]]:
    """Residual energy per time bin: [{t_start_s, t_end_s, energy_share, excess_ratio}]."""
    if len(time_s) == 0:
        return []
    edges = np.arange(time_s[0], time_s[-1] + bin_s, bin_s)
    index = np.clip(np.searchsorted(edges, time_s, side="right") - 1, 0, len(edges) - 1)
    total = float(np.sum(energy)) or 1.0
    out = []
    for k in range(len(edges)):
        inside = index == k
        if not inside.any():
            continue
        e = float(np.sum(energy[inside]))
        n = float(np.sum(noise_energy[inside]))
        out.append({"t_start_s": float(edges[k]), "t_end_s": float(edges[k] + bin_s), "energy_share": e / total,
                    "ratio_to_noise": e / n if n > 0 else float("inf")})
    return out
