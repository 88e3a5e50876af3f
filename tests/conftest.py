"""Shared fixtures of the test suite."""

from __future__ import annotations

from pathlib import Path

import pytest


@pytest.fixture(scope="session")
def ipbmotor_fmu(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Path of IPBMotor.fmu (the demo motor, with directional derivatives), built once per session."""
    from hybridfmu.fmu.build import build_fmu

    return build_fmu("IPBMotor", tmp_path_factory.mktemp("fmu") / "IPBMotor.fmu")


@pytest.fixture(scope="session")
def oscillator_fmu(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Path of Oscillator.fmu (2 states, no inputs, no directional derivatives), built once per session."""
    from hybridfmu.fmu.build import build_fmu

    return build_fmu("Oscillator", tmp_path_factory.mktemp("fmu") / "Oscillator.fmu")
