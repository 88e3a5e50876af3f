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


#: At most this many brackets (s_max + 1); the paper's R = 81, eta = 3 has 5. More means an eta so close to 1
#: that the search would plan (and the workflow schedule) an unbounded number of configurations.
MAX_BRACKETS = 20


def check_budget(R: float, eta: float, names: tuple[str, str] = ("R", "eta")) -> None:
    """Raise ValueError unless (R, eta) gives a real search: several brackets, each successive halving.

    Degenerate inputs: R or eta not a finite number; R < 1; eta <= 1 (no halving; log_eta undefined);
    R < eta (a single bracket of a single configuration trained to R: no search at all); more than
    :data:`MAX_BRACKETS` brackets (eta too close to 1 for R). ``names`` name R and eta in the message
    (e.g. ``config.hpo.R``).
    """
    r_name, eta_name = names
    for name, value in ((r_name, R), (eta_name, eta)):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ValueError(f"{name} = {value!r}: expected a finite number")
    if not R >= 1:
        raise ValueError(f"{r_name} = {R:g}: expected at least 1 (the maximum resource per configuration, in units)")
    if not eta > 1:
        raise ValueError(f"{eta_name} = {eta:g}: expected a reduction factor above 1 (the paper's 3)")
    if R < eta * (1 - 1e-9):
        raise ValueError(f"{r_name} = {R:g} is smaller than {eta_name} = {eta:g}: Hyperband would have one bracket "
                         "with a single configuration trained to R (no search); expected "
                         f"{r_name} >= {eta_name} (the paper: R = 81, eta = 3)")
    n_brackets = _s_max(R, eta) + 1
    if n_brackets > MAX_BRACKETS:
        raise ValueError(f"{r_name} = {R:g}, {eta_name} = {eta:g}: {n_brackets} brackets (log_eta R + 1); expected "
                         f"at most {MAX_BRACKETS} (a larger {eta_name} or a smaller {r_name})")


def _s_max(R: float, eta: float) -> int:
    return int(math.floor(math.log(R) / math.log(eta) + 1e-9))


def max_bracket(R: float, eta: float) -> int:
    """s_max = floor(log_eta(R)) (robust to rounding: R = 81, eta = 3 gives 4).

    Raises:
        ValueError: degenerate R and eta (:func:`check_budget`).
    """
    check_budget(R, eta)
    return _s_max(R, eta)


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
