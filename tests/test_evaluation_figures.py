"""Every figure function draws a readable PNG from synthetic data."""

import numpy as np
import pytest
from matplotlib import image

from hybridfmu.evaluation.figures import (PlotOptions, Trajectories, decimate_minmax, plot_time_offset,
                                          plot_trajectory, plot_zooms)

OPTIONS = PlotOptions(dpi=60, width_in=6, height_in=3, max_points=2000)


def _synthetic(quantity="angle"):
    t = np.linspace(0.0, 4.0, 4001)
    data = np.sin(t) * 10
    return Trajectories("validation", quantity, t, data, data + 0.3 * t ** 2, data + 0.05 * np.cos(9 * t),
                        zooms=[(2.0, 3.0), (3.5, 4.0)])


def _assert_png(path, min_width_px=200):
    assert path.is_file() and path.stat().st_size > 5000
    pixels = image.imread(path)
    assert pixels.shape[1] >= min_width_px
    # not a blank canvas: several distinct colours drawn
    assert len(np.unique(pixels.reshape(-1, pixels.shape[-1])[:, :3].round(2), axis=0)) > 10


@pytest.mark.parametrize("quantity", ["angle", "speed"])
def test_trajectory_and_zoom_figures(tmp_path, quantity):
    traj = _synthetic(quantity)
    _assert_png(plot_trajectory(traj, tmp_path / "whole.png", OPTIONS))
    _assert_png(plot_zooms(traj, tmp_path / "zoom.png", OPTIONS))


def test_zoom_without_interval_or_with_bad_shapes_fails(tmp_path):
    traj = _synthetic()
    traj.zooms = []
    with pytest.raises(ValueError, match="no zoom interval"):
        plot_zooms(traj, tmp_path / "z.png", OPTIONS)
    traj.fmu = traj.fmu[:-1]
    with pytest.raises(ValueError, match="differ in shape"):
        plot_trajectory(traj, tmp_path / "w.png", OPTIONS)


def test_time_offset_figure(tmp_path):
    t = np.arange(0, 0.02, 1e-4)
    _assert_png(plot_time_offset(t, np.tanh((t - 0.01) * 500), np.tanh((t - 0.0098) * 500),
                                 tmp_path / "offset.png", np.tanh((t - 0.01) * 500) + 0.01, input_delay_s=2e-4,
                                 maneuver="train", options=OPTIONS))


def test_decimation_keeps_extremes():
    t = np.linspace(0, 1, 100001)
    y = np.zeros_like(t)
    y[54321] = 7.0
    y[12345] = -3.0
    td, yd = decimate_minmax(t, y, 1000)
    assert td.size <= 1000 and yd.max() == 7.0 and yd.min() == -3.0
    assert np.all(np.diff(td) > 0)
