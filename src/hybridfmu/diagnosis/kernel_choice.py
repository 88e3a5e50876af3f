"""The length of the Hann kernel chosen from the data, when ``diagnosis.kernel_s`` is not set.

The diagnosis averages both sides of each state equation with a Hann kernel (:mod:`hybridfmu.diagnosis.residual`).
Too short a kernel leaves the measurement noise of the differentiated states in the equation error (its floor falls
with about the kernel length cubed); too long a kernel averages away the fast part of the gap and leaves fewer
independent fitting centres. The right length depends on the sampling, the noise and the dynamics of the case, so it
is read off the case's own fitting maneuvers:

- for lengths on a doubling grid (``MIN_KERNEL_SAMPLES``, 2 x that - 1, ...), the root mean square of each examined
  equation's kernel-averaged equation error at centres one kernel apart inside the segments;
- lengthening the kernel removes what the averaging removes: noise and fast content the model's equations cannot
  follow (interpolation, ripple, quantisation: more than the white-noise estimate of the diagnosis' noise floor
  covers), and past some length the gap itself. While it removes noise above a gap, each doubling lowers the RMS by
  a smaller share than the one before; a doubling that lowers it by a clearly larger share
  (``GAP_FALL_RATIO`` x) than the one before is averaging the gap away. The kernel is shared by the examined
  equations, so the rule looks at their mean relative fall: the first length is chosen at which a doubling lowers
  the residual RMS by less than ``CONVERGED_DROP`` on average (what is left is the gap the diagnosis explains) or
  by more than ``GAP_FALL_RATIO`` x the share the doubling before did;
- never longer than ``MAX_SPAN_FRACTION`` of the median segment (the bootstrap cuts segments into blocks of 20
  kernels).

The diagnosis report lists the lengths tried with each equation's RMS and the reason for the choice.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from hybridfmu.diagnosis.derivatives import hann_kernel, smooth_same

#: The shortest kernel tried (samples): the length the diagnosis used before it chose from the data.
MIN_KERNEL_SAMPLES = 9

#: A doubling of the kernel that lowers the examined equations' residual RMS by less than this share on average has
#: converged.
CONVERGED_DROP = 0.02

#: A doubling whose mean fall exceeds this multiple of the fall of the doubling before averages the gap away.
GAP_FALL_RATIO = 1.5

#: The kernel is at most this share of the median segment length (samples).
MAX_SPAN_FRACTION = 0.05


@dataclass(frozen=True)
class KernelChoice:
    """The chosen kernel and the evidence for it.

    Attributes:
        samples: chosen length (odd, samples); seconds = ``samples * dt_s``.
        dt_s: the sampling interval (s).
        lengths: (K,) the lengths tried (samples).
        rms: (K, n_eq) RMS of each examined equation's kernel-averaged equation error at each length (units of the
            state's derivative); NaN where no centre was inside a segment.
        equations: (n_eq,) names of the examined equations.
        reason: one sentence saying why this length.
    """

    samples: int
    dt_s: float
    lengths: tuple[int, ...]
    rms: np.ndarray
    equations: tuple[str, ...]
    reason: str

    @property
    def kernel_s(self) -> float:
        """The chosen length (s)."""
        return self.samples * self.dt_s

    def record(self) -> dict:
        """A JSON-ready account for the diagnosis' result file."""
        return {"kernel_s": self.kernel_s, "samples": self.samples, "lengths_samples": list(self.lengths),
                "rms": {name: _finite_list(self.rms[:, j]) for j, name in enumerate(self.equations)},
                "converged_drop": CONVERGED_DROP, "gap_fall_ratio": GAP_FALL_RATIO, "reason": self.reason}


def _finite_list(values: np.ndarray) -> list[float | None]:
    return [float(v) if np.isfinite(v) else None for v in values]


def kernel_lengths(max_samples: int) -> list[int]:
    """Odd lengths (samples) on a doubling grid, ``MIN_KERNEL_SAMPLES``, 2 n - 1, ... up to ``max_samples`` (at
    least the first)."""
    lengths = [MIN_KERNEL_SAMPLES]
    while 2 * lengths[-1] - 1 <= max_samples:
        lengths.append(2 * lengths[-1] - 1)
    return lengths


def residual_rms(residuals: Sequence[np.ndarray], inside: Sequence[np.ndarray], length: int,
                 equations: Sequence[int]) -> np.ndarray:
    """(n_eq,) RMS of the kernel-averaged residuals at centres ``length`` apart that lie inside the segments.

    Args:
        residuals: per maneuver, a raw equation error (M, n_x) (state units per s).
        inside: per maneuver, (M,) bool, the intervals inside its segments.
        length: kernel length (odd, samples).
        equations: state indices of the examined equations.
    """
    kernel = hann_kernel(length)
    values = []
    for residual, mask in zip(residuals, inside):
        filtered = smooth_same(np.asarray(residual, dtype=float)[:, list(equations)], kernel)
        half = length // 2
        centres = np.arange(half, filtered.shape[0] - half, length)
        centres = centres[mask[centres]]
        picked = filtered[centres]
        values.append(picked[np.all(np.isfinite(picked), axis=1)])
    stacked = np.concatenate(values, axis=0) if values else np.empty((0, len(equations)))
    if stacked.shape[0] == 0:
        return np.full(len(equations), np.nan)
    return np.sqrt(np.mean(stacked ** 2, axis=0))


def mean_fall(rms: np.ndarray, rms_longer: np.ndarray) -> float | None:
    """Mean relative fall (share) of the residual RMS from ``rms`` to ``rms_longer`` ((n_eq,) each) over the equations
    where both are finite and positive; None where none is."""
    usable = np.isfinite(rms) & np.isfinite(rms_longer) & (rms > 0)
    if not usable.any():
        return None
    return float(np.mean(1.0 - rms_longer[usable] / rms[usable]))


def choose_kernel(residuals: Sequence[np.ndarray], inside: Sequence[np.ndarray], equations: Sequence[int],
                  equation_names: Sequence[str], dt_s: float, median_span_samples: float) -> KernelChoice:
    """The kernel length of the module's rule for the fitting maneuvers' raw equation errors.

    Args:
        residuals: per fitting maneuver, the raw equation error (M, n_x) (state units per s).
        inside: per fitting maneuver, (M,) bool, the intervals inside its segments.
        equations, equation_names: state indices and names of the examined equations.
        dt_s: the sampling interval (s).
        median_span_samples: the median length of the fitting maneuvers' segments (samples).
    """
    if not residuals:
        raise ValueError("choose_kernel: no fitting maneuver")
    cap = max(int(MAX_SPAN_FRACTION * median_span_samples), MIN_KERNEL_SAMPLES)
    lengths = kernel_lengths(cap)
    rms = np.array([residual_rms(residuals, inside, n, equations) for n in lengths])
    names = tuple(equation_names)
    previous = None
    for k in range(len(lengths) - 1):
        fall = mean_fall(rms[k], rms[k + 1])
        lowers = f"doubling it to {lengths[k + 1]} samples lowers the examined equations' residual RMS by"
        if fall is None:
            reason = f"no fitting centre inside a segment at {lengths[k + 1]} samples"
        elif fall < CONVERGED_DROP:
            reason = (f"{lowers} {fall:.1%} on average, less than {CONVERGED_DROP:.0%}" if fall >= 0 else
                      f"doubling it to {lengths[k + 1]} samples raises the examined equations' residual RMS by "
                      f"{-fall:.1%} on average")
        elif previous is not None and fall > GAP_FALL_RATIO * previous:
            reason = (f"{lowers} {fall:.1%} on average, more than {GAP_FALL_RATIO:g} x the {previous:.1%} of the "
                      f"doubling before: it would average the gap away")
        else:
            previous = fall
            continue
        return KernelChoice(lengths[k], dt_s, tuple(lengths), rms, names, reason)
    reason = (f"the residual RMS still falls at the longest kernel tried, {MAX_SPAN_FRACTION:.0%} of the median "
              f"segment ({cap} samples)")
    return KernelChoice(lengths[-1], dt_s, tuple(lengths), rms, names, reason)
