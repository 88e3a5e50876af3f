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


#: Modules that run the workflow end to end, longest first. They are collected first so that, with the test
#: command's two workers (pytest-xdist, one module per worker: --dist loadfile, --no-loadscope-reorder), both
#: workers start on them at once and the short tests fill in after; alone, the order changes nothing.
WORKFLOW_MODULES = ("test_slurm.py", "test_workflow_e2e.py", "test_workflow_resume.py", "test_new_fmu_e2e.py",
                    "test_withheld.py", "test_diagnosis_overflow.py")


def pytest_collection_modifyitems(session: pytest.Session, config: pytest.Config, items: list[pytest.Item]) -> None:
    def rank(item: pytest.Item) -> int:
        name = item.path.name
        return WORKFLOW_MODULES.index(name) if name in WORKFLOW_MODULES else len(WORKFLOW_MODULES)

    items.sort(key=rank)  # stable: the order within a module and among the other modules is kept
