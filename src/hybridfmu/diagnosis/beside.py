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

#: Seconds a stopped worker is given to end after SIGTERM (and after SIGKILL) before the caller goes on.
STOP_GRACE_S = 5.0

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
    and :meth:`results` runs the parts in order in the caller. Used as a context manager, the workers are stopped
    when the block ends before the results were asked for (e.g. on an error in the caller)."""

    def __init__(self, parts: dict[str, Callable[[], Any]], workers: int) -> None:
        self.parts = dict(parts)
        self._futures: dict[str, Future] = {}
        self._pool: ProcessPoolExecutor | None = None
        self._results: dict[str, Any] | None = None
        if int(workers) > 1 and self.parts and can_fork():
            _PARTS.clear()
            _PARTS.update(self.parts)
            self._pool = ProcessPoolExecutor(max_workers=min(int(workers) - 1, len(self.parts)),
                                             mp_context=multiprocessing.get_context("fork"))
            self._futures = {key: self._pool.submit(_run_part, key) for key in self.parts}

    def __enter__(self) -> "Beside":
        return self

    def __exit__(self, *_exc: object) -> None:
        self.stop()

    @property
    def in_workers(self) -> bool:
        """Whether the parts run in worker processes."""
        return bool(self._futures)

    def stop(self) -> None:
        """End the workers, parts still running among them; nothing once the results are in or without workers."""
        if self._pool is None:
            return
        processes = list((getattr(self._pool, "_processes", None) or {}).values())
        self._pool.shutdown(wait=False, cancel_futures=True)
        for process in processes:
            if process.is_alive():
                process.terminate()
        for process in processes:  # a worker that inherited a handler of SIGTERM may outlive it: kill it
            process.join(timeout=STOP_GRACE_S)
            if process.is_alive():
                process.kill()
                process.join(timeout=STOP_GRACE_S)
        self._pool = None
        _PARTS.clear()

    def results(self) -> dict[str, Any]:
        """Key -> result of every part (a part's exception is raised here)."""
        if self._results is None:
            if self._futures:
                try:
                    self._results = {key: future.result() for key, future in self._futures.items()}
                finally:
                    self.stop()
            else:
                self._results = {key: part() for key, part in self.parts.items()}
        return self._results
