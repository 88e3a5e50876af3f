"""Derivatives of measured signals on a uniform grid, and the matched smoothing kernel.

The equation error compares what the measurements did with what the model says they
should have done. Measured states are noisy and quantised, so their derivatives are
estimated in the *weak form*: over each sampling interval k the measured change is
``(x[k+1] - x[k]) / dt`` and both sides of the state equation are averaged with the same
smooth kernel (a Hann window). Because the kernel is applied to the difference quotients,
the estimate telescopes to a weighted difference of the samples (noise is suppressed by
the window length) and no filter mismatch arises between measured and modelled side.
Savitzky-Golay smoothing gives low-noise signals (e.g. a speed for nonlinear regressors).
"""

from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view


def odd_window(window_s: float, dt_s: float, minimum: int = 3) -> int:
    """Number of samples (odd, >= ``minimum``) that spans ``window_s`` on a grid of ``dt_s``."""
    if window_s <= 0 or dt_s <= 0:
        raise ValueError(f"window_s and dt_s must be positive, got {window_s} and {dt_s}")
    n = max(int(round(window_s / dt_s)), minimum)
    return n if n % 2 == 1 else n + 1


def hann_kernel(n_samples: int) -> np.ndarray:
    """Hann window of ``n_samples`` (odd) points, zero-free, normalised to sum 1. Shape (n,)."""
    if n_samples < 1 or n_samples % 2 == 0:
        raise ValueError(f"kernel length must be odd and positive, got {n_samples}")
    k = np.arange(1, n_samples + 1)
    weights = np.sin(np.pi * k / (n_samples + 1)) ** 2
    return weights / weights.sum()


def interval_rates(x: np.ndarray, dt_s: float) -> np.ndarray:
    """Difference quotients over each sampling interval. ``x`` (N, ...) -> (N-1, ...) per second."""
    x = np.asarray(x, dtype=float)
    return (x[1:] - x[:-1]) / dt_s


def interval_means(x: np.ndarray) -> np.ndarray:
    """Mean of the two end samples of each interval. ``x`` (N, ...) -> (N-1, ...)."""
    x = np.asarray(x, dtype=float)
    return 0.5 * (x[1:] + x[:-1])


def smooth_same(signal: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Centred weighted average along axis 0; NaN where the kernel does not fit.

    ``signal`` (M, ...) and ``kernel`` (W,) with W odd -> (M, ...). NaN inputs propagate.
    """
    signal = np.asarray(signal, dtype=float)
    width = len(kernel)
    half = width // 2
    out = np.full(signal.shape, np.nan)
    if signal.shape[0] < width:
        return out
    from scipy.signal import oaconvolve  # imported where used: scipy.signal takes ~1.5 s to import

    flat = signal.reshape(signal.shape[0], -1)
    result = oaconvolve(flat, kernel[::-1, None], mode="valid", axes=0)
    out.reshape(signal.shape[0], -1)[half:signal.shape[0] - half] = result
    return out


def smooth_at(signal: np.ndarray, kernel: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """Centred weighted average evaluated only at the sample indices ``centres``.

    ``signal`` (M, ...), ``kernel`` (W,), ``centres`` (K,) integer indices with
    ``W//2 <= centre < M - W//2`` -> (K, ...). Cheaper than ``smooth_same`` for sparse centres.
    """
    signal = np.asarray(signal, dtype=float)
    width = len(kernel)
    half = width // 2
    centres = np.asarray(centres, dtype=int)
    if len(centres) and (centres.min() < half or centres.max() >= signal.shape[0] - half):
        raise ValueError("smoothing centres too close to the ends of the signal")
    flat = signal.reshape(signal.shape[0], -1)
    windows = sliding_window_view(flat, width, axis=0)  # (M-W+1, F, W)
    values = windows[centres - half] @ kernel
    return values.reshape((len(centres),) + signal.shape[1:])


def savgol_smooth(signal: np.ndarray, window: int, order: int = 2) -> np.ndarray:
    """Savitzky-Golay smoothing along axis 0 (window odd, in samples). Same shape as ``signal``."""
    signal = np.asarray(signal, dtype=float)
    if signal.shape[0] <= window:
        return signal.copy()
    from scipy.signal import savgol_filter

    return savgol_filter(signal, window, order, axis=0, mode="interp")


def savgol_derivative(signal: np.ndarray, dt_s: float, window: int, order: int = 2,
                      deriv: int = 1) -> np.ndarray:
    """Savitzky-Golay derivative of order ``deriv`` along axis 0, in units per second**deriv."""
    signal = np.asarray(signal, dtype=float)
    if signal.shape[0] <= window:
        raise ValueError(f"signal of {signal.shape[0]} samples is shorter than the window {window}")
    from scipy.signal import savgol_filter

    return savgol_filter(signal, window, max(order, deriv), deriv=deriv, delta=dt_s, axis=0, mode="interp")


def _mad_std(values: np.ndarray) -> np.ndarray:
    """Robust std (median absolute deviation) of ``values`` (M, C) along axis 0; zeros when empty."""
    if values.shape[0] == 0:
        return np.zeros(values.shape[1])
    return 1.4826 * np.median(np.abs(values - np.median(values, axis=0)), axis=0)


def white_noise_std(signal: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """Robust estimate of the white measurement-noise level (std per sample) of a signal, per column.

    For white noise e of std s, var(diff3(e)) = 20 s^2, while smooth signal content hardly
    contributes at a high sampling rate; the median absolute deviation makes it robust to
    transients. A channel that was interpolated onto a shifted grid has less noise per sample than
    at low frequency, so its level is underrated (reported as a limitation of the noise floor).
    ``signal`` (N,) or (N, C); ``mask`` (N,) selects the samples (runs of at least 13 samples).
    """
    signal = np.asarray(signal, dtype=float)
    flat = signal.reshape(signal.shape[0], -1)
    if mask is not None:
        keep = np.asarray(mask, dtype=bool)
        runs = np.flatnonzero(np.diff(np.concatenate([[0], keep.astype(int), [0]])))
        pieces = [flat[a:b] for a, b in zip(runs[::2], runs[1::2]) if b - a > 12]
    else:
        pieces = [flat]
    if not pieces:
        out = np.zeros(flat.shape[1])
    else:
        out = _mad_std(np.concatenate([np.diff(p, n=3, axis=0) for p in pieces], axis=0)) / np.sqrt(20.0)
        for j in range(flat.shape[1]):
            step = quantisation_step(np.concatenate([np.diff(p[:, j]) for p in pieces]))
            if step > 0:
                out[j] = max(out[j], step / np.sqrt(12.0))
    return out.reshape(signal.shape[1:]) if signal.ndim > 1 else np.float64(out[0])


def quantisation_step(differences: np.ndarray, share: float = 0.95) -> float:
    """The quantisation step of a signal from its sample differences (0 if it is not quantised).

    A signal counts as quantised when at least ``share`` of its nonzero differences are integer
    multiples (to 1 %) of the smallest one; its quantisation error is then at least step/sqrt(12)
    whatever the third differences say (a slowly moving quantised signal has mostly zero differences).
    """
    magnitudes = np.abs(differences[np.isfinite(differences)])
    nonzero = magnitudes[magnitudes > 1e-12 * max(float(np.max(magnitudes, initial=0.0)), 1e-300)]
    if len(nonzero) < 20:
        return 0.0
    step = float(np.percentile(nonzero, 1))
    ratio = nonzero / step
    if np.mean(np.abs(ratio - np.round(ratio)) < 0.01) < share:
        return 0.0
    return step
