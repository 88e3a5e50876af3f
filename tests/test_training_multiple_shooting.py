"""Multiple shooting: windows tile a record, each restarts from the measured state; the neural FMU's batched
windows are its whole-record simulation restarted."""

import numpy as np
import pytest
import torch

from hybridfmu.training.multiple_shooting import (MIN_WINDOW_SAMPLES, batched_window_rows, window_samples,
                                                 window_starts, windowed_trajectory)
from hybridfmu.training.inference import simulate_neural_fmu, simulate_neural_fmu_windows
from test_training_trainer import H, NumpyPendulum, make_model, pendulum_inputs
from hybridfmu.training.data import ManeuverArrays
from hybridfmu.training.statistics import data_statistics
from test_model_layers import Pendulum


def test_windows_tile_the_record_and_restart_from_the_given_state():
    assert window_starts(11, 4).tolist() == [0, 4, 8]
    assert batched_window_rows(11, 4)[0].tolist() == [0, 4] and batched_window_rows(11, 4)[1] == 2
    assert batched_window_rows(9, 4)[0].tolist() == [0, 4] and batched_window_rows(9, 4)[1] == 0
    assert window_samples(0.1, 1e-3, 10.0) == 100 and window_samples(None, 1e-3, 10.0) == 50
    assert window_samples(1e-4, 1e-3, 10.0) == MIN_WINDOW_SAMPLES
    with pytest.raises(ValueError, match="windows.length_s"):
        window_samples(-1.0, 1e-3, 10.0)
    time_s = np.arange(11) * 0.1
    x_start = np.column_stack([np.arange(11) * 10.0])

    def ramp(t, u, x0):  # x' = 1: the state grows with time from where the window starts
        return x0[None, :] + (t - t[0])[:, None]

    out = windowed_trajectory(ramp, time_s, np.zeros((11, 0)), x_start, 4)
    assert out[:, 0] == pytest.approx([0, 0.1, 0.2, 0.3, 40, 40.1, 40.2, 40.3, 80, 80.1, 80.2])

    def failing(t, u, x0):
        if t[0] > 0.5:
            raise FloatingPointError("diverged")
        return ramp(t, u, x0)

    out = windowed_trajectory(failing, time_s, np.zeros((11, 0)), x_start, 4)
    assert np.isnan(out[8:]).all() and np.isfinite(out[:8]).all()


@pytest.fixture(scope="module")
def pendulum():
    n = 700
    u = pendulum_inputs(n, seed=3)
    phase = np.arange(n) * H * 30.0
    x = np.column_stack([0.1 * np.sin(phase), 3.0 * np.cos(phase), 0.05 * np.sin(2 * phase)])
    arrays = ManeuverArrays(name="w", time_s=np.arange(n) * H, u=u, x_init=x, targets=x[:, :2].copy(),
                            spans=np.array([[0, n - 1]]), state_names=Pendulum.state_names,
                            input_names=Pendulum.input_names, target_states=["p", "v"],
                            target_signals=["position", "rate"], measured_states=Pendulum.state_names)
    model = make_model(data_statistics(arrays, NumpyPendulum()), seed=2)
    with torch.no_grad():
        model.ann.output.weight.normal_(0.0, 0.3)  # an ANN that corrects: the windows must carry it too
    return model, arrays


def test_batched_windows_are_the_model_restarted(pendulum):
    model, arrays = pendulum
    whole = simulate_neural_fmu(model, arrays.time_s, arrays.u, arrays.x_init[0])
    # one window over the whole record is the whole-record simulation
    np.testing.assert_allclose(simulate_neural_fmu_windows(model, arrays.time_s, arrays.u, arrays.x_init, 10_000),
                               whole, rtol=0, atol=1e-12)
    # inputs held around every window boundary: the samples a delayed stage input reads beyond a window's ends
    # are then the same whether the window sees the whole record or only its own slice
    steps = 64
    u = arrays.u.copy()
    for boundary in [*window_starts(u.shape[0], steps)[1:], u.shape[0] - 1]:
        u[max(boundary - 8, 0):boundary + 9] = u[boundary]
    windows = simulate_neural_fmu_windows(model, arrays.time_s, u, arrays.x_init, steps, batch=3)
    for start in window_starts(arrays.time_s.size, steps):
        end = min(int(start) + steps, arrays.time_s.size - 1)
        alone = simulate_neural_fmu(model, arrays.time_s[start:end + 1], u[start:end + 1], arrays.x_init[start])
        np.testing.assert_allclose(windows[start:end], alone[:end - start], rtol=0, atol=1e-9)
        assert windows[start] == pytest.approx(arrays.x_init[start])
