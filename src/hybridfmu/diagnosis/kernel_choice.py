"""The length of the Hann kernel from the model's own time scale, when ``diagnosis.kernel_s`` is not set.

The diagnosis averages both sides of each state equation with a Hann kernel (:mod:`hybridfmu.diagnosis.residual`).
Too short a kernel leaves the measurement noise of the differentiated states in the equation error (its floor falls
with about the kernel length cubed); too long a kernel averages away dynamics the model describes and leaves fewer
independent fitting centres. The scale that separates the two is the model's own: the fastest mode of the examined
state equations along the measured trajectory.

- At samples inside the segments of the fitting maneuvers, the eigenvalues of the FMU's Jacobian restricted to the
  examined equations (d f_i / d x_j for examined i, j) give each mode's time scale ``1 / |lambda|`` (decay and
  oscillation alike: a lightly damped oscillation counts by its frequency); the fastest mode's, in the median over
  the samples, is the model's time scale ``tau``.
- The kernel spans ``TIME_CONSTANTS`` of it: a Hann kernel of length 2 tau passes the band of that mode up to about
  2.25 x its corner frequency 1 / (2 pi tau) (half power) and averages what lies above, which the model cannot
  describe and where the differentiated noise lives.
- It is at least ``MIN_KERNEL_SAMPLES`` samples and at most ``MAX_SPAN_FRACTION`` of the median segment (the
  bootstrap cuts segments into blocks of 20 kernels). A model whose examined equations have no dynamics of their
  own (every eigenvalue zero) gets the shortest kernel.

The diagnosis report gives the chosen length, ``tau`` and the reason.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

#: The shortest kernel (samples).
MIN_KERNEL_SAMPLES = 9

#: The kernel spans this many of the model's fastest time scales.
TIME_CONSTANTS = 2.0

#: The kernel is at most this share of the median segment length.
MAX_SPAN_FRACTION = 0.05

#: Jacobian samples used per maneuver (evenly spread over the samples inside its segments).
MAX_SAMPLES_PER_MANEUVER = 2000


@dataclass(frozen=True)
class KernelChoice:
    """The chosen kernel and the evidence for it.

    Attributes:
        samples: chosen length (odd, samples); seconds: :attr:`kernel_s`.
        dt_s: the sampling interval (s).
        tau_s: the model's fastest time scale along the data (s), median over the samples; None without dynamics.
        tau_quantiles_s: its 10 %, 50 % and 90 % quantiles over the samples (s), or None.
        reason: one sentence saying why this length.
    """

    samples: int
    dt_s: float
    tau_s: float | None
    tau_quantiles_s: tuple[float, float, float] | None
    reason: str

    @property
    def kernel_s(self) -> float:
        """The chosen length (s)."""
        return self.samples * self.dt_s

    def record(self) -> dict:
        """A JSON-ready account for the diagnosis' result file."""
        return {"kernel_s": self.kernel_s, "samples": self.samples, "tau_s": self.tau_s,
                "tau_quantiles_s": None if self.tau_quantiles_s is None else list(self.tau_quantiles_s),
                "time_constants": TIME_CONSTANTS, "reason": self.reason}


def fastest_time_scales(jacobians: Sequence[np.ndarray], inside: Sequence[np.ndarray],
                        equations: Sequence[int]) -> np.ndarray:
    """(K,) the fastest mode's time scale ``1 / max |lambda|`` (s) of the examined equations' Jacobian block at up to
    ``MAX_SAMPLES_PER_MANEUVER`` samples inside the segments of each maneuver; infinite where every eigenvalue is 0.

    Args:
        jacobians: per maneuver, the model Jacobian d f / d x (M, n_x, n_x) along the data (1/s).
        inside: per maneuver, (M,) bool, the samples inside its segments.
        equations: state indices of the examined equations.
    """
    index = np.asarray(list(equations), dtype=int)
    scales = []
    for jacobian, mask in zip(jacobians, inside):
        rows = np.flatnonzero(mask)
        if rows.size == 0:
            continue
        rows = rows[np.linspace(0, rows.size - 1, min(rows.size, MAX_SAMPLES_PER_MANEUVER)).astype(int)]
        block = np.asarray(jacobian, dtype=float)[rows][:, index][:, :, index]
        block = block[np.all(np.isfinite(block), axis=(1, 2))]
        if block.shape[0] == 0:
            continue
        fastest = np.max(np.abs(np.linalg.eigvals(block)), axis=1)
        with np.errstate(divide="ignore"):
            scales.append(np.where(fastest > 0.0, 1.0 / fastest, np.inf))
    return np.concatenate(scales) if scales else np.empty(0)


def choose_kernel(jacobians: Sequence[np.ndarray], inside: Sequence[np.ndarray], equations: Sequence[int],
                  dt_s: float, median_span_samples: float) -> KernelChoice:
    """The kernel length of the module's rule.

    Args:
        jacobians: per fitting maneuver, the model Jacobian d f / d x (M, n_x, n_x) along the data (1/s).
        inside: per fitting maneuver, (M,) bool, the samples inside its segments.
        equations: state indices of the examined equations.
        dt_s: the sampling interval (s).
        median_span_samples: the median length of the fitting maneuvers' segments (samples).
    """
    cap = max(int(MAX_SPAN_FRACTION * median_span_samples), MIN_KERNEL_SAMPLES)
    cap -= 1 - cap % 2  # odd
    scales = fastest_time_scales(jacobians, inside, equations)
    finite = scales[np.isfinite(scales)]
    if finite.size * 2 <= scales.size:  # no dynamics at most samples (or no sample at all)
        return KernelChoice(MIN_KERNEL_SAMPLES, dt_s, None, None,
                            "the model's examined equations have no dynamics of their own along the data (their "
                            "Jacobian's eigenvalues are zero at most samples): the shortest kernel")
    tau_s = float(np.median(scales))
    quantiles = tuple(float(q) for q in np.quantile(scales, [0.1, 0.5, 0.9]))
    wanted = int(round(TIME_CONSTANTS * tau_s / dt_s))
    samples = min(max(wanted | 1, MIN_KERNEL_SAMPLES), cap)
    reason = (f"{TIME_CONSTANTS:g} x the model's fastest time scale along the fitting maneuvers, {tau_s:.4g} s "
              f"(the median of 1 / max |eigenvalue| of the examined equations' Jacobian; 10-90 %: "
              f"{quantiles[0]:.4g}-{quantiles[2]:.4g} s)")
    if samples == MIN_KERNEL_SAMPLES and wanted < MIN_KERNEL_SAMPLES:
        reason += f", raised to the shortest kernel ({MIN_KERNEL_SAMPLES} samples)"
    elif samples == cap and (wanted | 1) > cap:
        reason += f", held to {MAX_SPAN_FRACTION:.0%} of the median segment ({cap} samples)"
    return KernelChoice(samples, dt_s, tau_s, quantiles, reason)
