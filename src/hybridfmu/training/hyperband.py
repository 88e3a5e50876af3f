"""Hyperband (Li et al. 2018) bracket arithmetic and successive-halving selection.

With maximum resource R (in resource units) and reduction factor eta: s_max = floor(log_eta R),
B = (s_max + 1) R. Bracket s (s = s_max .. 0) starts n = ceil(B / R * eta^s / (s + 1)) configurations
with r = R eta^-s units each; rung i holds n_i = floor(n eta^-i) configurations trained to
r_i = r eta^i units (cumulative, a rung resumes the previous one), for i = 0 .. s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence


@dataclass(frozen=True)
class Rung:
    """Rung ``index`` of a bracket: ``n_configs`` configurations trained to ``resource_units`` (cumulative)."""

    index: int
    n_configs: int
    resource_units: float


@dataclass(frozen=True)
class Bracket:
    """Bracket ``s``: ``n_configs`` sampled configurations, successive halving over ``rungs``."""

    s: int
    n_configs: int
    rungs: tuple[Rung, ...]

    @property
    def last_rung(self) -> int:
        return self.rungs[-1].index


def max_bracket(R: float, eta: float) -> int:
    """s_max = floor(log_eta(R)) (robust to rounding: R = 81, eta = 3 gives 4)."""
    if not R >= 1 or not eta > 1:
        raise ValueError(f"hyperband: need R >= 1 and eta > 1, got R={R}, eta={eta}")
    return int(math.floor(math.log(R) / math.log(eta) + 1e-9))


def hyperband_brackets(R: float, eta: float) -> list[Bracket]:
    """All brackets, most exploratory first (s = s_max .. 0)."""
    s_max = max_bracket(R, eta)
    budget = (s_max + 1) * R
    brackets = []
    for s in range(s_max, -1, -1):
        n = int(math.ceil(budget / R * eta ** s / (s + 1) - 1e-9))
        r = R * eta ** (-s)
        rungs = tuple(Rung(i, int(math.floor(n * eta ** (-i) + 1e-9)), r * eta ** i) for i in range(s + 1))
        brackets.append(Bracket(s, n, rungs))
    return brackets


def bracket_by_index(R: float, eta: float, s: int) -> Bracket:
    for bracket in hyperband_brackets(R, eta):
        if bracket.s == s:
            return bracket
    raise ValueError(f"hyperband: no bracket {s} for R={R}, eta={eta} (brackets 0..{max_bracket(R, eta)})")


def total_configurations(R: float, eta: float) -> int:
    return sum(bracket.n_configs for bracket in hyperband_brackets(R, eta))


def rank_results(results: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Results sorted best first by ``objective`` (lower is better); failed or non-finite results last,
    ties broken by configuration index."""
    def key(result: dict[str, Any]):
        value = result.get("objective")
        ok = result.get("status") == "ok" and isinstance(value, (int, float)) and math.isfinite(value)
        return (0 if ok else 1, value if ok else 0.0, int(result["config"]))
    return sorted(results, key=key)


def select_survivors(results: Sequence[dict[str, Any]], n_keep: int) -> list[int]:
    """Configuration indices of the ``n_keep`` best successful results (failed ones never survive)."""
    ranked = [r for r in rank_results(results)
              if r.get("status") == "ok" and math.isfinite(float(r.get("objective", math.inf)))]
    return [int(r["config"]) for r in ranked[:max(0, n_keep)]]
