"""Parts of the diagnosis run in forked workers beside the caller: the same results as in the caller."""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest

from diagnosis_models import msd_maneuvers, msd_problem
from hybridfmu.diagnosis.beside import Beside, can_fork
from hybridfmu.diagnosis.run import run_diagnosis

needs_fork = pytest.mark.skipif(not can_fork(), reason="worker processes cannot be forked here")


def ended(process, timeout_s: float = 30.0) -> bool:
    """Whether a worker process has ended within ``timeout_s``: its exit code is known, or, where /proc tells, its
    pid names no process or a zombie (the pool's own thread may reap it first; ``is_alive`` then cannot tell)."""
    import time

    deadline = time.monotonic() + timeout_s
    while True:
        process.join(timeout=0.5)
        if not process.is_alive():
            return True
        stat = Path(f"/proc/{process.pid}/stat")
        if stat.parent.parent.is_dir():
            try:
                if stat.read_text().rsplit(")", 1)[1].split()[0] in ("Z", "X"):
                    return True
            except FileNotFoundError:
                return True
        if time.monotonic() > deadline:
            return False


@needs_fork
def test_parts_run_in_other_processes_and_return_their_results():
    beside = Beside({"a": lambda: (os.getpid(), 1), "b": lambda: (os.getpid(), 2)}, workers=3)
    assert beside.in_workers
    results = beside.results()
    assert {key: value for key, (_, value) in results.items()} == {"a": 1, "b": 2}
    assert all(pid != os.getpid() for pid, _ in results.values())


@needs_fork
def test_workers_are_ended_when_the_block_ends_before_the_results():
    import time

    with Beside({"slow": lambda: time.sleep(60)}, workers=2) as beside:
        processes = list(beside._pool._processes.values())
        assert beside.in_workers and processes
    assert all(ended(process) for process in processes)


@needs_fork
def test_a_worker_that_ignores_sigterm_is_killed_when_the_block_ends():
    """Forked workers inherit the caller's signal handlers: one that survives SIGTERM (a handler doing nothing, as a
    library may install) is killed, so no worker outlives its block."""
    import signal
    import time

    previous = signal.signal(signal.SIGTERM, lambda *_: None)
    try:
        with Beside({"slow": lambda: time.sleep(60)}, workers=2) as beside:
            processes = list(beside._pool._processes.values())
            time.sleep(0.5)  # the worker is in the part, with the inherited handler
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert processes and all(ended(process) for process in processes)


def test_one_worker_runs_the_parts_in_the_caller_when_asked():
    ran = []
    beside = Beside({"a": lambda: ran.append("a") or os.getpid()}, workers=1)
    assert not beside.in_workers and ran == []
    assert beside.results() == {"a": os.getpid()} and ran == ["a"]


@needs_fork
def test_an_exception_in_a_worker_is_raised_by_results():
    def fails() -> None:
        raise ValueError("part failed")

    beside = Beside({"ok": lambda: 1, "bad": fails}, workers=2)
    with pytest.raises(ValueError, match="part failed"):
        beside.results()


@needs_fork
def test_the_selections_on_each_maneuver_alone_are_the_same_beside_the_main_one():
    """A Coulomb friction the model lacks, two fitting maneuvers: the stability check's selections on each maneuver
    alone, in two workers beside the main selection, give the record of one process, every figure to the bit."""
    def friction(x, u):
        out = np.zeros_like(x)
        out[:, 1] = -0.4 * np.tanh(x[:, 1] / 0.005)
        return out

    records = []
    for workers in (1, 3):
        problem, model = msd_problem()
        result = run_diagnosis(problem, model, msd_maneuvers(friction, duration_s=10.0), open_loop=False,
                               workers=workers)
        records.append(result.which)
    one, beside = records
    assert [c["effect"] for c in one.chosen] == ["coulomb(v)"]
    assert one.chosen[0]["stability"] == beside.chosen[0]["stability"]
    per_maneuver = one.equations["v"]["selection_per_maneuver"]
    assert per_maneuver == beside.equations["v"]["selection_per_maneuver"]
    assert sorted(per_maneuver) == ["train", "validation"] and per_maneuver["train"] == ["coulomb(v)"]
    assert all(math.isfinite(p["value"]) for p in beside.chosen[0]["parameters"])
