"""A velocity held at rest by its diagnosed friction (a Karnopp stick band), and its band chosen from the data.

The diagnosis fits friction only where the configured standstill state moves (``diagnosis.standstill``): below
its threshold the fitted friction law (a smoothed sign) is an extrapolation, and a simulation that uses it lets a
body at rest creep under any push, however small. :class:`StandstillHold` gives the simulation the rest state
the fitted friction implies: within ``|x_j| < band`` the friction terms of the state's own equation hold it where
they can (the push without them is at most their value at the band's edge) and the rate then drives the state to
zero (``-rate_per_s x_j``); where they cannot, the body slides with that edge friction. Outside the band nothing
changes. :mod:`hybridfmu.fmu.effects` (``hold``) and :class:`hybridfmu.diagnosis.corrected_model.CorrectedModel`
evaluate it alike.

:func:`choose_hold` takes the band from the fitting maneuvers: each candidate (fractions of the standstill
threshold, and no hold) simulated open loop over the whole maneuvers, the smallest mean normalised gap wins.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

LOGGER = logging.getLogger("hybridfmu.diagnosis")

#: effect kinds that are friction of their own variable (they oppose its sign)
FRICTION_KINDS = ("coulomb", "scaled_coulomb")
#: candidate bands as fractions of the standstill threshold (``diagnosis.standstill.below``)
BAND_FRACTIONS = (0.03, 0.1, 0.3, 1.0)
#: the rate that drives a held state to zero, in sampling intervals (-x_j / (RATE_SAMPLES dt)); RK4 on the
#: sample grid stays stable for any value above 0.36
RATE_SAMPLES = 5.0


@dataclass(frozen=True)
class StandstillHold:
    """``state`` (name) is held at rest within ``|state| < band`` (state units) by the friction terms of its own
    equation; a held state decays at ``rate_per_s`` (1/s)."""

    state: str
    band: float
    rate_per_s: float

    def describe(self, unit: str = "") -> str:
        return f"{self.state} held at rest by its friction below {self.band:.4g}{' ' + unit if unit else ''}"


def friction_rows(row_terms: list[tuple[int, Any, np.ndarray, dict[str, float]]], state: int) -> list[int]:
    """Indices into ``row_terms`` ((equation, effect, coefficients, setting)) of the friction terms of ``state``
    in its own equation."""
    return [n for n, (equation, effect, _, _) in enumerate(row_terms)
            if equation == state and effect.kind in FRICTION_KINDS and getattr(effect, "variable", None) == state]


def held_rate(before: np.ndarray, friction: np.ndarray, edge: np.ndarray, x_j: np.ndarray,
              rate_per_s: float) -> tuple[np.ndarray, np.ndarray]:
    """The equation's rate within the band and whether the friction holds: ``before`` (N,) the rate with every
    term, ``friction`` (N,) its friction terms' sum at the state, ``edge`` (N,) at the band's edge on the side
    the push without them points to, ``x_j`` (N,) the state. Same operations as ``effects.c``."""
    push = before - friction
    held = push * (push + edge) <= 0.0
    return np.where(held, -rate_per_s * x_j, push + edge), held


def choose_hold(state: str, threshold: float, dt_s: float, gap_of: Callable[[StandstillHold | None], float]
                ) -> tuple[StandstillHold | None, list[dict[str, Any]]]:
    """The hold (or None) whose open-loop gap over the fitting maneuvers, ``gap_of(hold)``, is the smallest, and
    every candidate's record (``band`` (None: no hold), ``gap``). Candidates: :data:`BAND_FRACTIONS` of the
    standstill ``threshold`` (state units); ties and failed simulations (NaN) keep no hold."""
    candidates: list[StandstillHold | None] = [None] + [
        StandstillHold(state, float(fraction * threshold), 1.0 / (RATE_SAMPLES * dt_s)) for fraction in BAND_FRACTIONS]
    records, best, best_gap = [], None, float("inf")
    for hold in candidates:
        gap = float(gap_of(hold))
        records.append({"band": None if hold is None else hold.band, "gap": gap})
        LOGGER.info("standstill hold %s: open-loop gap over the fitting maneuvers %.4g",
                    "off" if hold is None else f"below {hold.band:.4g}", gap)
        if np.isfinite(gap) and gap < best_gap:
            best, best_gap = hold, gap
    return best, records
