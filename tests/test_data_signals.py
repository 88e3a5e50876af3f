"""FMU arrays from an ingested frame by the case's roles: inputs in FMU order, measured states, targets."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from hybridfmu.data.roles import CaseRoles, Signal
from hybridfmu.data.errors import DataError
from hybridfmu.data.signals import input_array, signal_array, state_array, target_array, time_array


def make_roles() -> CaseRoles:
    """Two tanks: FMU inputs (pump, valve), states (h1, h2, T) of which h2 and h1 are measured, target h2."""
    signals = {name: Signal(name, unit, unit, name, channel=name) for name, unit in
               [("pump_v", "V"), ("valve", ""), ("level_1", "m"), ("level_2", "m")]}
    return CaseRoles(signals=signals, transforms=[], state_names=["h1", "h2", "T"], input_names=["u_pump", "u_valve"],
                     inputs={"u_pump": "pump_v", "u_valve": "valve"}, states={"h1": "level_1", "h2": "level_2"},
                     target_weights={"h2": 1.0})


@pytest.fixture()
def frame():
    n = 7
    return pd.DataFrame({"time_s": np.arange(n) * 0.1, "valve": np.linspace(0, 1, n), "level_2": np.arange(n) + 10.0,
                         "pump_v": np.arange(n) * 2.0, "level_1": -np.arange(n, dtype=float)})


def test_inputs_in_fmu_order(frame):
    roles = make_roles()
    u = input_array(frame, roles)
    assert u.shape == (7, 2) and u.dtype == np.float64
    np.testing.assert_array_equal(u[:, 0], frame["pump_v"])
    np.testing.assert_array_equal(u[:, 1], frame["valve"])
    np.testing.assert_array_equal(time_array(frame), frame["time_s"])


def test_measured_states_and_targets(frame):
    roles = make_roles()
    x = state_array(frame, roles)
    assert x.shape == (7, 2)
    np.testing.assert_array_equal(x[:, 0], frame["level_1"])
    np.testing.assert_array_equal(x[:, 1], frame["level_2"])
    np.testing.assert_array_equal(state_array(frame, roles, ["h2"])[:, 0], frame["level_2"])
    np.testing.assert_array_equal(target_array(frame, roles)[:, 0], frame["level_2"])
    assert signal_array(frame, []).shape == (7, 0)


def test_errors_name_the_state_and_the_column(frame):
    roles = make_roles()
    with pytest.raises(DataError, match=r"state\(s\) \['T'\] are not measured: config\.roles\.states"):
        state_array(frame, roles, ["h1", "T"])
    with pytest.raises(DataError, match=r"column 'pump_v' missing"):
        input_array(frame.drop(columns=["pump_v"]), roles)
