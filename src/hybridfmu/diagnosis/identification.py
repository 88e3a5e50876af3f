"""Whether the data identify a fitted effect parameter: an uncertainty that covers what the model gets wrong.

The regression's standard error measures the noise only; it stays tight when the effect's shape is wrong, when
the maneuvers disagree, or when a term left out would take over part of the effect's work. A parameter's combined
standard error is therefore the largest of four:

- the regression's (``se``), from the residual variance and the design;
- the bootstrap's over segments (``se_bootstrap``), where it was drawn;
- the spread between the fitting maneuvers, each fitted alone: the sample standard deviation s of the n
  per-maneuver values (``stability.per_maneuver``; for two maneuvers |a - b| / sqrt 2), widened to what a 90 %
  interval from so few values must be: s t_(0.95, n - 1) / 1.645 (Student's t with n - 1 degrees of freedom;
  x3.84 for two maneuvers, x1.31 for five), since s from two or three values can be far below the true spread;
- the shift to its values with a rival fitted beside the chosen effects (a candidate the data support that the
  selection left out for its small practical size, :class:`hybridfmu.diagnosis.selection.Rival`): the largest
  |shift| / 1.645 (on the log scale for a log-scaled setting), so the 90 % interval reaches the value the data
  would give with the rival in the model, since they do not decide between the two.

Its 90 % interval is value +- 1.645 combined SEs. A size (a coefficient, a friction level, an amplitude, a
relative parameter error, a time offset) is identified when that interval neither covers zero nor spans more than
a factor of ten, i.e. when 1.645 SE < (9/11) |value|. A positive scale searched on a log scale (a smoothing, a
Stribeck velocity, a current scale) has its interval on that scale, value x/÷ exp(1.645 SE / value), and is
identified when it spans no more than a factor of ten. A location (a threshold, a level, a phase) has no such scale
and is judged by nothing here; a setting held fixed or an integer (an order, a number of harmonics) has no standard
error and is not judged either.

An effect is confirmed by the data when one of its sizes is identified (:func:`confirmed`). One whose every judged
size is not identified improved the pooled fit, but the data leave open whether it is there at all (the maneuvers
disagree on its sign, or a rival would take its place): it stays in the model and is reported as unconfirmed, not
named as a finding.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

#: two-sided 90 % quantile of the normal distribution
Z_90 = 1.6448536269514722
#: largest ratio of the interval's ends of an identified size
MAX_RANGE_RATIO = 10.0
#: parameter names that give a location, not a size (a name, or a prefix ending in "_")
LOCATION_PARAMETERS = ("threshold", "level", "phase_")


def parameter_matches(name: str, patterns: list[str] | tuple[str, ...]) -> bool:
    """Whether the parameter ``name`` is one of ``patterns``: a name, or a prefix ending in ``_`` (``phase_``)."""
    return any(name == p or (p.endswith("_") and name.startswith(p)) for p in patterns)


def is_location(name: str) -> bool:
    """Whether the physical parameter ``name`` is a location (threshold, level, phase) rather than a size."""
    return parameter_matches(name, LOCATION_PARAMETERS)


def spread_widening(n_values: int) -> float:
    """t_(0.95, n - 1) / z_0.95: how much wider a 90 % interval from the standard deviation of ``n_values`` values
    must be than the normal one (3.84 for two values, 1.0 in the limit)."""
    from scipy.stats import t

    return float(t.ppf(0.95, n_values - 1) / Z_90)


def rival_se(value: float, alternatives: list[float] | None, log_scale: bool = False) -> float | None:
    """The SE whose 90 % interval around ``value`` just reaches the farthest of the ``alternatives`` (its values with
    a rival fitted beside, module docstring): max |a - value| / 1.645, or on the log scale
    value max |ln(a / value)| / 1.645 (alternatives <= 0 ignored there); None without a finite alternative."""
    finite = [float(a) for a in alternatives or [] if a is not None and math.isfinite(float(a))]
    if log_scale:
        finite = [a for a in finite if a > 0.0]
        if not finite or not value > 0.0:
            return None
        return value * max(abs(math.log(a / value)) for a in finite) / Z_90
    return max(abs(a - value) for a in finite) / Z_90 if finite else None


def combined_se(row: dict[str, Any], per_maneuver: dict[str, float] | None,
                alternatives: list[float] | None = None, log_scale: bool = False) -> float | None:
    """The largest of the regression's SE, the bootstrap's SE, the per-maneuver values' standard deviation widened
    for their number (:func:`spread_widening`) and the rivals' shift (:func:`rival_se` of ``alternatives``; module
    docstring), or None when the parameter has none of them."""
    candidates = [row.get("se"), row.get("se_bootstrap")]
    values = [float(v) for v in (per_maneuver or {}).values() if v is not None and math.isfinite(float(v))]
    if len(values) > 1:
        candidates.append(float(np.std(values, ddof=1)) * spread_widening(len(values)))
    value = row.get("value")
    if alternatives and value is not None and math.isfinite(float(value)):
        candidates.append(rival_se(float(value), alternatives, log_scale))
    finite = [float(c) for c in candidates if c is not None and math.isfinite(float(c))]
    return max(finite) if finite else None


def identification(row: dict[str, Any], per_maneuver: dict[str, float] | None,
                   log_scale: bool = False, alternatives: list[float] | None = None) -> dict[str, Any]:
    """The fields a physical parameter ``row`` (``name``, ``value``, ``se``, ``se_bootstrap``) gains:
    ``se_combined``, ``interval_90`` ([low, high] or None) and ``identified`` (True, False, or None where not
    judged) with ``not_identified_because`` (words, or None). ``log_scale``: a positive scale searched on a log
    scale (its interval is taken on that scale; a value <= 0, the setting switched off, is not judged).
    ``alternatives``: its values with each rival fitted beside the chosen effects (:func:`combined_se`)."""
    value = row.get("value")
    se = combined_se(row, per_maneuver, alternatives, log_scale)
    out: dict[str, Any] = {"se_combined": se, "interval_90": None, "identified": None, "not_identified_because": None}
    if se is None or value is None or not math.isfinite(float(value)):
        return out
    value = float(value)
    if log_scale:
        if value <= 0.0:
            return out
        factor = math.exp(Z_90 * se / value)
        out["interval_90"] = [value / factor, value * factor]
        if factor * factor > MAX_RANGE_RATIO:
            out["identified"] = False
            out["not_identified_because"] = f"its 90 % interval spans more than a factor {MAX_RANGE_RATIO:g}"
        else:
            out["identified"] = True
        return out
    low, high = value - Z_90 * se, value + Z_90 * se
    out["interval_90"] = [low, high]
    if is_location(str(row.get("name", ""))):
        return out
    if low <= 0.0 <= high:
        out["identified"], out["not_identified_because"] = False, "its 90 % interval covers zero"
    elif max(abs(low), abs(high)) > MAX_RANGE_RATIO * min(abs(low), abs(high)):
        out["identified"] = False
        out["not_identified_because"] = f"its 90 % interval spans more than a factor {MAX_RANGE_RATIO:g}"
    else:
        out["identified"] = True
    return out


def confirmed(rows: list[dict[str, Any]], size_names: list[str]) -> bool | None:
    """Whether the data confirm an effect: one of its size parameters (``size_names``, :meth:`hybridfmu.diagnosis.
    effects.Effect.size_parameters`; a name ending in ``_`` matches every row it begins) is identified. False when
    every judged size parameter is not identified (the 90 % intervals of its size all cover zero or span more than a
    factor ten: the maneuvers, the bootstrap or a rival leave open whether the effect is there at all); None when no
    size parameter was judged. ``rows``: the effect's physical parameters with their :func:`identification`."""
    judged = [row.get("identified") for row in rows if parameter_matches(str(row.get("name", "")), size_names)]
    judged = [j for j in judged if j is not None]
    if not judged:
        return None
    return any(judged)


#: the correlation of two chosen effects' estimates above which the data do not tell them apart
GROUP_CORRELATION = 0.9


def indistinguishable_groups(names: list[str], sizes: list[int], cov: np.ndarray,
                             threshold: float = GROUP_CORRELATION) -> list[dict[str, Any]]:
    """Chosen effects whose estimates the data do not tell apart: linked when any coefficient of one correlates with
    any of the other's at |r| >= ``threshold`` in the joint fit's covariance (their sensitivities look alike, so
    only their joint effect is determined), joined into groups.

    Args:
        names: the chosen effects in the fit's order; sizes: their numbers of coefficients (same order).
        cov: (sum(sizes), sum(sizes)) covariance of the joint fit's coefficients.

    Returns:
        One entry per group of two or more: ``effects`` (in ``names`` order) and ``pairs`` (each linked pair with its
        ``correlation``, the signed coefficient correlation of largest magnitude).
    """
    cov = np.asarray(cov, dtype=float)
    starts = np.concatenate([[0], np.cumsum(sizes)]).astype(int)
    if cov.shape != (starts[-1], starts[-1]) or len(names) < 2:
        return []
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(sd, sd)
    parent = list(range(len(names)))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    pairs = []
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            block = corr[starts[i]:starts[i + 1], starts[j]:starts[j + 1]]
            finite = block[np.isfinite(block)]
            if not finite.size:
                continue
            r = float(finite[np.argmax(np.abs(finite))])
            if abs(r) >= threshold:
                pairs.append({"effects": [names[i], names[j]], "correlation": r})
                parent[root(j)] = root(i)
    groups: dict[int, list[int]] = {}
    for i in range(len(names)):
        groups.setdefault(root(i), []).append(i)
    out = []
    for members in groups.values():
        if len(members) > 1:
            member_names = [names[i] for i in members]
            out.append({"effects": member_names,
                        "pairs": [p for p in pairs if p["effects"][0] in member_names]})
    return out
