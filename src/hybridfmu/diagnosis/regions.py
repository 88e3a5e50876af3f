"""Where the equation error lies: its energy over operating regions and over time.

Regions come from the declared signals: for every measured state its value band, the band of its
rate |dx/dt| (measured, kernel-averaged), the sign of its rate and the neighbourhood of reversals of
that sign; for every input its level band; the end stops when ``model.end_stop`` is configured; a
configured standstill. Band edges are quantiles over all maneuvers (``diagnosis.regions``). For each
region the share of the residual energy above the noise floor is compared with the share of time
spent there; the regions where the energy concentrates most are ranked and stated in words. Over
time, the residual energy per time bin shows when the model departs from the data.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass
class RegionSamples:
    """Per-sample residual energies and region memberships of one equation (pooled over maneuvers).

    Attributes:
        energy: (K,) squared kernel-averaged equation error (equation unit^2).
        noise_energy: (K,) its expected value from measurement noise alone.
        signed: (K,) the signed equation error.
        families: family name -> (labels, (K,) index of each sample's label).
    """

    energy: np.ndarray
    noise_energy: np.ndarray
    signed: np.ndarray
    families: dict[str, tuple[list[str], np.ndarray]]


def band_family(values: np.ndarray, edges: list[float], name: str, unit: str) -> tuple[list[str], np.ndarray]:
    """Labels and (K,) band index of ``values`` for increasing band ``edges``."""
    edges = sorted(set(float(e) for e in edges))
    if not edges:
        return [f"all {name}"], np.zeros(len(values), dtype=int)
    labels = [f"{name} < {edges[0]:.4g} {unit}".rstrip()]
    labels += [f"{a:.4g} <= {name} < {b:.4g} {unit}".rstrip() for a, b in zip(edges[:-1], edges[1:])]
    labels.append(f"{name} >= {edges[-1]:.4g} {unit}".rstrip())
    return labels, np.searchsorted(edges, values, side="right")


def reversal_mask(rate: np.ndarray, threshold: float, half_window: int) -> np.ndarray:
    """(K,) bool: within ``half_window`` samples of a reversal of the sign of ``rate`` (from > +threshold
    to < -threshold or back)."""
    state = np.zeros(len(rate), dtype=int)
    state[rate > threshold] = 1
    state[rate < -threshold] = -1
    nonzero = np.flatnonzero(state)
    mask = np.zeros(len(rate), dtype=bool)
    if len(nonzero) < 2:
        return mask
    change = state[nonzero[1:]] != state[nonzero[:-1]]
    for start, end in zip(nonzero[:-1][change], nonzero[1:][change]):
        mask[max(start - half_window, 0):min(end + half_window + 1, len(mask))] = True
    return mask


def region_table(samples: RegionSamples) -> list[dict[str, Any]]:
    """One row per region: time share, energy share, share of the energy above noise, mean signed residual."""
    total_energy = float(np.sum(samples.energy))
    rows = []
    for family, (labels, index) in samples.families.items():
        family_rows = []
        for k, label in enumerate(labels):
            inside = index == k
            if not inside.any():
                continue
            energy = float(np.sum(samples.energy[inside]))
            above = max(energy - float(np.sum(samples.noise_energy[inside])), 0.0)
            family_rows.append({
                "family": family, "region": label, "time_share": float(inside.mean()),
                "energy_share": energy / total_energy if total_energy > 0 else 0.0,
                "excess_energy": above, "mean_residual": float(np.mean(samples.signed[inside])),
                "samples": int(inside.sum()),
            })
        family_excess = sum(r["excess_energy"] for r in family_rows)
        for row in family_rows:
            row["excess_share"] = row.pop("excess_energy") / family_excess if family_excess > 0 else 0.0
            row["concentration"] = row["energy_share"] / row["time_share"] if row["time_share"] > 0 else 0.0
        rows += family_rows
    return rows


def ranked_statements(rows: list[dict[str, Any]], unit: str, top: int, at_noise: bool) -> list[str]:
    """Sentences for the regions where the residual energy above noise concentrates most."""
    if at_noise:
        return ["the residual is at the noise level: no region stands out"]
    candidates = [r for r in rows if 0.01 <= r["time_share"] < 0.99]
    candidates.sort(key=lambda r: r["excess_share"] - r["time_share"], reverse=True)
    return [f"{100 * r['excess_share']:.0f} % of the residual energy above noise "
            f"({100 * r['energy_share']:.0f} % of all) lies where {r['region']}, {100 * r['time_share']:.0f} % of "
            f"the time (mean residual {r['mean_residual']:+.3g} {unit})" for r in candidates[:top]]


def time_bins(time_s: np.ndarray, energy: np.ndarray, noise_energy: np.ndarray, bin_s: float) -> list[dict[str, Any]]:
    """Residual energy per time bin: [{t_start_s, t_end_s, energy_share, ratio_to_noise}]."""
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
