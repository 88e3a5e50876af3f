"""Every figure function draws a readable PNG from synthetic data."""

import numpy as np
import pytest
from matplotlib import image

from hybridfmu.data.roles import Signal
from hybridfmu.evaluation.figures import (PlotOptions, Trajectories, decimate_minmax, plot_time_offset,
                                          plot_trajectory, plot_zooms, squared_unit)

OPTIONS = PlotOptions(dpi=60, width_in=6, height_in=3, max_points=2000)
SIGNALS = {"angle": Signal("angle", "rad", "deg", "rotor angle"), "speed": Signal("speed", "rad/s", "rpm", "rotor speed"),
           "level": Signal("level", "", "", "fill level")}


def _synthetic(signal="angle"):
    t = np.linspace(0.0, 4.0, 4001)
    data = np.sin(t) * 10
    return Trajectories("validation", SIGNALS[signal], t, data, data + 0.3 * t ** 2, data + 0.05 * np.cos(9 * t),
                        zooms=[(2.0, 3.0), (3.5, 4.0)])


def _assert_png(path, min_width_px=200):
    assert path.is_file() and path.stat().st_size > 5000
    pixels = image.imread(path)
    assert pixels.shape[1] >= min_width_px
    # not a blank canvas: several distinct colours drawn
    assert len(np.unique(pixels.reshape(-1, pixels.shape[-1])[:, :3].round(2), axis=0)) > 10


@pytest.mark.parametrize("signal", ["angle", "speed", "level"])
def test_trajectory_and_zoom_figures(tmp_path, signal):
    traj = _synthetic(signal)
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
    data = np.column_stack([np.tanh((t - 0.01) * 500), t * 3])
    fmu = np.column_stack([np.tanh((t - 0.0098) * 500), t * 3.1])
    _assert_png(plot_time_offset(t, [SIGNALS["speed"], SIGNALS["angle"]], data, fmu, tmp_path / "offset.png",
                                 data + 0.01, input_delay_s=2e-4, maneuver="train", options=OPTIONS))
    with pytest.raises(ValueError, match="1 signals"):
        plot_time_offset(t, [SIGNALS["speed"]], data, fmu, tmp_path / "bad.png")


def test_squared_units():
    assert squared_unit("rad") == "rad²" and squared_unit("rad/s") == "(rad/s)²" and squared_unit("") == "-"


def test_decimation_keeps_extremes():
    t = np.linspace(0, 1, 100001)
    y = np.zeros_like(t)
    y[54321] = 7.0
    y[12345] = -3.0
    td, yd = decimate_minmax(t, y, 1000)
    assert td.size <= 1000 and yd.max() == 7.0 and yd.min() == -3.0
    assert np.all(np.diff(td) > 0)


def _write_search(root):
    """Result files of a tiny search: bracket 1 (2 configs, 2 rungs; c1 stops), bracket 0 (1 config, failed)."""
    import json

    def write(bracket, rung, config, resource_s, objective, status="ok", hash_="h"):
        folder = root / f"b{bracket}" / f"r{rung}" / f"c{config}"
        folder.mkdir(parents=True)
        curve = [[r, 1.0 / (1 + r) + 0.01 * config] for r in np.linspace(0.1, resource_s, 20)]
        curve[3][1] = None
        folder.joinpath("result.json").write_text(json.dumps({
            "trial_id": f"b{bracket}c{config}", "bracket": bracket, "config": config, "rung": rung,
            "hash": f"{hash_}{bracket}{config}",
            "resource_s": resource_s, "objective": objective, "status": status, "curve": curve,
            "hyperparameters": {"lr": 1e-5, "width": 8}}))

    write(1, 0, 0, 1.0, 0.5)
    write(1, 0, 1, 1.0, 0.7)
    write(1, 1, 0, 3.0, 0.3)
    write(0, 0, 0, 3.0, None, status="diverged")
    best = root / "best.json"
    best.write_text('{"trial_id": "b1c0"}')
    return best


def test_histories_and_search_figures(tmp_path):
    from hybridfmu.evaluation.figures import plot_hyperband, plot_training_curves
    from hybridfmu.evaluation.history import read_histories

    best = _write_search(tmp_path)
    search = read_histories(tmp_path, best)
    assert [t.trial_id for t in search.trials] == ["b0c0", "b1c0", "b1c1"]
    b1c0 = search.trials[1]
    assert [r["rung"] for r in b1c0.rungs] == [0, 1] and b1c0.curve[-1, 0] == pytest.approx(3.0)
    assert np.isnan(b1c0.curve[3, 1]) and search.trials[0].status == "diverged" and search.brackets == [0, 1]
    _assert_png(plot_training_curves(search, tmp_path / "curves.png", OPTIONS))
    _assert_png(plot_hyperband(search, tmp_path / "hyperband.png", OPTIONS))


def test_histories_missing_are_named(tmp_path):
    from hybridfmu.evaluation.history import read_histories

    with pytest.raises(FileNotFoundError, match="no trial results"):
        read_histories(tmp_path)
    folder = tmp_path / "b0" / "r0" / "c0"
    folder.mkdir(parents=True)
    (folder / "result.json").write_text('{"trial_id": "b0c0"}')
    with pytest.raises(ValueError, match=r"result\.json: field 'bracket' missing"):
        read_histories(tmp_path)


def test_results_of_an_earlier_search_are_skipped(tmp_path):
    import json

    from hybridfmu.evaluation.history import read_histories

    best = _write_search(tmp_path)
    plan = {"brackets": [{"bracket": 1, "configs": [{"config": 0, "hash": "h10"}, {"config": 1, "hash": "other"}]},
                         {"bracket": 0, "configs": [{"config": 0, "hash": "h00"}]}]}
    (tmp_path / "plan.json").write_text(json.dumps(plan))
    search = read_histories(tmp_path, best)
    assert [t.trial_id for t in search.trials] == ["b0c0", "b1c0"]
