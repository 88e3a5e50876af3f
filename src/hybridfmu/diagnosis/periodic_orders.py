"""The orders of the periodic effects, found from the data rather than configured.

A periodic effect in a state x of period P (``diagnosis.periodic``) has an order k, the number of its periods
per P (a cogging torque of 12 slots per revolution has order 12 per revolution). With
``diagnosis.effects.periodic_max_order`` null (the default) its orders are searched in two steps before the
selection:

1. **The largest order the data resolve.** The selection fits kernel-averaged terms: sin(2 pi k x / P) averaged
   over a kernel while x moves. The faster x moves and the higher k, the more of the term the kernel averages
   away. Orders are scanned upward from 1; the scan stops at the first order whose kernel averages keep less
   than ``MIN_RELATIVE_ENERGY_RETAINED`` of the term's energy at the fitting centres (an order the kernel
   flattens cannot be told from noise), or at ``ORDER_LIMIT``.
2. **The orders in the residual.** For every order up to that limit, the share of the equation error's energy
   that a sine and a cosine of that order explain (the residual's spectrum over the position). The
   ``periodic_orders`` highest local maxima of this spectrum are the orders the selection searches, each with
   1..``periodic_harmonics`` harmonics (orders k, 2k, ...).

Every quantity is computed at the same centres with the same kernel as the selection's designs
(:class:`hybridfmu.diagnosis.selection.DesignCache`), so the search sees what the selection will fit.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from hybridfmu.diagnosis.selection import DesignCache, ManeuverFitData

LOGGER = logging.getLogger("hybridfmu.diagnosis")

#: an order is resolvable while the kernel averages keep at least this share of its energy (0..1)
MIN_RELATIVE_ENERGY_RETAINED = 0.1
#: the highest order ever scanned (periods per configured period)
ORDER_LIMIT = 512


@dataclass(frozen=True)
class OrderSearch:
    """What the search found for one periodic effect.

    Attributes:
        max_order: the largest order the data resolve (0: not even order 1).
        orders: the orders the selection searches (strongest first; empty when ``max_order`` is 0).
        explained_share: (max_order,) share of the equation error's energy explained by order 1..max_order alone.
    """

    max_order: int
    orders: tuple[int, ...]
    explained_share: np.ndarray

    def record(self) -> dict[str, Any]:
        """JSON form: the resolvable order, the searched orders and their explained shares."""
        return {"max_order_resolved": self.max_order, "orders": list(self.orders),
                "explained_share": {str(k): float(self.explained_share[k - 1]) for k in self.orders}}


def _window_phases(data: ManeuverFitData, variable: int, period: float) -> np.ndarray:
    """(n_centres, W) phase 2 pi x / P of state ``variable`` in the kernel window (W samples) of each fitting
    centre of ``data``."""
    width = len(data.kernel)
    rows = np.asarray(data.centres, dtype=int)[:, None] + np.arange(width)[None, :] - width // 2
    return 2.0 * math.pi * np.asarray(data.inputs.x[rows, variable], dtype=float) / period


def averaged_phasors(maneuvers: list[ManeuverFitData], variable: int, period: float, max_order: int
                     ) -> np.ndarray:
    """Kernel averages of exp(i k 2 pi x / P) at the fitting centres of ``maneuvers``, orders k = 1..``max_order``.

    Returns (n_centres summed over the maneuvers, max_order) complex: the real part is the averaged cosine
    regressor, the imaginary part the averaged sine, as :class:`hybridfmu.diagnosis.library.Periodic` fits them
    (orders are built by repeated multiplication; they differ from direct evaluation by rounding only).
    """
    columns = []
    for data in maneuvers:
        unit = np.exp(1j * _window_phases(data, variable, period))
        power = np.ones_like(unit)
        weights = np.asarray(data.kernel, dtype=float)
        out = np.empty((len(data.centres), max_order), dtype=complex)
        for k in range(max_order):
            power = power * unit
            out[:, k] = power @ weights
        columns.append(out)
    return np.concatenate(columns, axis=0) if columns else np.zeros((0, max_order), dtype=complex)


def retained_energy(phasors: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """(n_orders,) share of each order's energy the kernel averages keep, mean over the centres: 1 where x stands
    still in every window, near 0 where the order's period passes many times within one.

    ``phasors``: (n_centres, n_orders) from :func:`averaged_phasors`; ``kernel``: (W,) the weights they were
    averaged with.
    """
    return np.mean(np.abs(phasors) ** 2, axis=0) / float(np.sum(kernel)) ** 2 if len(phasors) else \
        np.zeros(phasors.shape[1])


def resolvable_max_order(phasors: np.ndarray, kernel: np.ndarray) -> int:
    """The largest order k such that the kernel averages keep at least ``MIN_RELATIVE_ENERGY_RETAINED`` of the
    energy of every order 1..k (the scan upward stops at the first order below); 0 when order 1 already falls
    below (the data do not resolve the period at all). ``phasors``: (n_centres, n_orders) up to the highest order
    scanned."""
    below = np.flatnonzero(retained_energy(phasors, kernel) < MIN_RELATIVE_ENERGY_RETAINED)
    return int(below[0]) if len(below) else phasors.shape[1]


def order_spectrum(phasors: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Share of the energy of ``target`` (n,) that a sine and a cosine of each order explain on their own.

    ``phasors``: (n, n_orders) complex kernel-averaged exp(i k 2 pi x / P) (:func:`averaged_phasors`) ->
    (n_orders,) in 0..1.
    """
    energy = float(target @ target)
    shares = np.zeros(phasors.shape[1])
    if energy <= 0.0:
        return shares
    for k in range(phasors.shape[1]):
        design = np.stack([phasors[:, k].imag, phasors[:, k].real], axis=1)
        gram = design.T @ design
        right = design.T @ target
        try:
            coef = np.linalg.solve(gram, right)
        except np.linalg.LinAlgError:
            coef = np.linalg.lstsq(design, target, rcond=None)[0]
        shares[k] = float(right @ coef) / energy
    return np.clip(shares, 0.0, 1.0)


def strongest_peaks(spectrum: np.ndarray, count: int) -> tuple[int, ...]:
    """The orders (1-based) of the ``count`` highest local maxima of ``spectrum`` (n_orders,), highest first.

    A local maximum is at least as high as both neighbours (the ends compare with their one neighbour), so a
    smooth trend over the low orders (a load that rises with the position) takes one place, not all of them.
    """
    values = np.asarray(spectrum, dtype=float)
    if not len(values) or count < 1:
        return ()
    padded = np.concatenate([[-np.inf], values, [-np.inf]])
    peaks = [k for k in range(1, len(values) + 1) if padded[k] >= padded[k - 1] and padded[k] >= padded[k + 1]
             and values[k - 1] > 0.0]
    peaks.sort(key=lambda k: (-values[k - 1], k))
    return tuple(peaks[:count])


def search_orders(cache: DesignCache, names: list[str], equation: int, phasors: np.ndarray,
                  count: int) -> OrderSearch:
    """The order search for a periodic effect in ``equation`` on the fitting maneuvers ``names`` of ``cache``: the
    resolvable order, then the ``count`` strongest peaks of the equation error's spectrum up to it. ``phasors``:
    (n_centres, ORDER_LIMIT) of the effect's state over ``names`` (:func:`averaged_phasors`; the same for every
    equation)."""
    max_order = resolvable_max_order(phasors, cache.maneuvers[names[0]].kernel)
    if max_order == 0:
        return OrderSearch(0, (), np.zeros(0))
    spectrum = order_spectrum(phasors[:, :max_order], cache.target(equation, names))
    return OrderSearch(max_order, strongest_peaks(spectrum, count), spectrum)


def narrow_periodic_orders(candidates: list[Any], cache: DesignCache, names: list[str], count: int,
                           problem: Any) -> tuple[list[Any], dict[str, dict[str, Any]], dict[str, str]]:
    """Give every periodic candidate whose orders are not configured (``orders`` None) the orders found in the data.

    Returns (the candidates, those the data cannot resolve left out; effect label -> :meth:`OrderSearch.record`;
    effect label -> why it was left out). A label is ``<effect> in d<state>/dt``.
    """
    kept: list[Any] = []
    searches: dict[str, dict[str, Any]] = {}
    skipped: dict[str, str] = {}
    phasors: dict[tuple[int, float], np.ndarray] = {}  # per (state, period): shared by its equations
    for effect in candidates:
        if effect.kind != "periodic" or getattr(effect, "orders", ()) is not None:
            kept.append(effect)
            continue
        label = f"{effect.name} in d{problem.state_names[effect.equation]}/dt"
        key = (effect.variable, effect.period)
        if key not in phasors:
            phasors[key] = averaged_phasors([cache.maneuvers[n] for n in names], *key, ORDER_LIMIT)
        found = search_orders(cache, names, effect.equation, phasors[key], count)
        searches[label] = found.record()
        if not found.orders:
            skipped[label] = (f"the fitting kernel keeps less than {MIN_RELATIVE_ENERGY_RETAINED:.0%} of even "
                              f"order 1 of the period along the data")
            continue
        effect.orders = list(found.orders)
        LOGGER.info("%s: orders up to %d resolved; searched: %s (explained shares %s)", label, found.max_order,
                    list(found.orders), ", ".join(f"{found.explained_share[k - 1]:.3g}" for k in found.orders))
        kept.append(effect)
    return kept, searches, skipped
