"""Restarted open-loop windows simulated side by side equal the windows simulated one by one."""

from __future__ import annotations

import numpy as np

from hybridfmu.diagnosis.corrected_model import simulate, simulate_windows
from hybridfmu.fmu import load_fmu, simulate_open_loop


def test_windows_side_by_side_equal_one_by_one_including_end_stops(ipbmotor_fmu):
    model = load_fmu(ipbmotor_fmu)
    dt_s, n = 1e-4, 1200
    time_s = np.arange(n) * dt_s
    t = time_s[:, None]
    # rotating duty pattern (drives the rotor), load torque 0.05 N m, 12 V
    phase = 2 * np.pi * 30.0 * t + np.array([0.0, -2 * np.pi / 3, 2 * np.pi / 3])
    u = np.column_stack([0.5 + 0.2 * np.sin(phase), np.full(n, 12.0), np.full(n, 0.05)])
    first = np.arange(0, n - 100, 100)
    x0 = np.column_stack([np.zeros(len(first)), np.linspace(-5, 5, len(first)),
                          np.linspace(0.3, 2.0, len(first)), np.linspace(-40, 40, len(first))])
    x0[0, 2], x0[0, 3] = 0.0, 0.0      # starts on the retract stop
    x0[1, 2], x0[1, 3] = 0.002, -30.0  # runs into the retract stop within the window

    def correction(x, u_rows):  # a friction-like term: (N, 4), (N, 5) -> (N, 4)
        out = np.zeros_like(x)
        out[:, 3] = -200.0 * np.tanh(x[:, 3] / 0.5) - 0.1 * x[:, 3]
        return out

    def nothing(x, u_rows):  # a correction called back from Python: the windows run side by side in NumPy
        return np.zeros_like(x)

    for corr in (nothing, correction):
        batch = simulate_windows(model, simulate_open_loop, time_s, u, x0, first, 100, corr)
        for w, start in enumerate(first):
            piece = slice(start, start + 101)
            one = simulate(model, simulate_open_loop, time_s[piece], u[piece], x0[w], corr)
            # the same scheme (hybridfmu.runge_kutta) in NumPy and in the shim's C: the same numbers to the bit
            np.testing.assert_array_equal(batch[w], one)
    assert np.min(batch[1, :, 2]) == 0.0  # the stop was reached and handled
    # without a correction every stage runs in C: the windows one by one, the same states as side by side
    np.testing.assert_array_equal(simulate_windows(model, simulate_open_loop, time_s, u, x0, first, 100, None),
                                  simulate_windows(model, simulate_open_loop, time_s, u, x0, first, 100, nothing))
