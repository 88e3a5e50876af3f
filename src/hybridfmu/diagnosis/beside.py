"""Independent parts of a computation run in forked worker processes while the caller goes on.

The diagnosis' stability check repeats the whole effect selection on each fitting maneuver alone; those
selections depend on nothing the main selection computes, so with more than one core they run beside it.
Workers are forked (they inherit the loaded FMU, the prepared data and the design caches; nothing is
pickled on the way in) and return plain results. With one worker, or where processes cannot be forked
(Windows, macOS' default), the parts run in the caller when their results are asked for. Either way the
same single-threaded computations give the same numbers to the bit.
"""

from __future__ import annotations

import multiprocessing
from concurrent.futures import Future, ProcessPoolExecutor
from typing import Any, Callable

#: The parts of the running :class:`Beside`, read by the forked workers (set before they are forked).
_PARTS: dict[str, Callable[[], Any]] = {}


def _run_part(key: str) -> Any:
    return _PARTS[key]()


def can_fork() -> bool:
    """Whether worker processes can be forked here."""
    return "fork" in multiprocessing.get_all_start_methods()


class Beside:
    """Run ``parts`` (key -> function of no arguments returning a picklable result) in ``workers - 1`` forked
    processes, started now; :meth:`results` waits for them. With ``workers`` <= 1 (or no fork) nothing starts
    and :meth:`results` runs the parts in order in the caller."""

    def __init__(self, parts: dict[str, Callable[[], Any]], workers: int) -> None:
        self.parts = dict(parts)
        self._futures: dict[str, Future] = {}
        self._pool: ProcessPoolExecutor | None = None
        if int(workers) > 1 and self.parts and can_fork():
            _PARTS.clear()
            _PARTS.update(self.parts)
            self._pool = ProcessPoolExecutor(max_workers=min(int(workers) - 1, len(self.parts)),
                                             mp_context=multiprocessing.get_context("fork"))
            self._futures = {key: self._pool.submit(_run_part, key) for key in self.parts}

    @property
    def in_workers(self) -> bool:
        """Whether the parts run in worker processes."""
        return self._pool is not None

    def results(self) -> dict[str, Any]:
        """Key -> result of every part (a part's exception is raised here)."""
        if self._pool is None:
            return {key: part() for key, part in self.parts.items()}
        try:
            return {key: future.result() for key, future in self._futures.items()}
        finally:
            self._pool.shutdown()
            _PARTS.clear()
