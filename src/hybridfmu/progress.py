"""Rule logging and progress reporting for long-running work.

``setup_rule_logging`` sends log records to the rule's log file (and stderr), starting with the job's
kernel-choice and thread settings (:func:`hybridfmu.numerics.describe_numerics`);
``Progress`` emits periodic lines with the rate and the estimated time left.
"""

from __future__ import annotations

import logging
import sys
import time
from pathlib import Path
from typing import Any

from hybridfmu.numerics import describe_numerics

LOG_FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"


def setup_rule_logging(log_path: str | Path | None, level: int = logging.INFO) -> logging.Logger:
    """Configure the root logger to write to ``log_path`` (if given) and to stderr, and log an error that ends
    the process (an uncaught exception, with its traceback) there too: the rule's log file says why its job
    failed, not only Snakemake's output.

    Returns the ``hybridfmu`` logger. Safe to call more than once (handlers are replaced).
    """
    root = logging.getLogger()
    for handler in list(root.handlers):
        root.removeHandler(handler)
    formatter = logging.Formatter(LOG_FORMAT)
    stream = logging.StreamHandler(sys.stderr)
    stream.setFormatter(formatter)
    root.addHandler(stream)
    if log_path:
        log_path = Path(log_path)
        log_path.parent.mkdir(parents=True, exist_ok=True)
        file_handler = logging.FileHandler(log_path, mode="w")
        file_handler.setFormatter(formatter)
        root.addHandler(file_handler)
    root.setLevel(level)
    sys.excepthook = _log_uncaught
    logger = logging.getLogger("hybridfmu")
    logger.info(describe_numerics())
    return logger


def _log_uncaught(kind: type[BaseException], error: BaseException, trace: Any) -> None:
    """``sys.excepthook`` of a rule's process: the error and its traceback through the logging handlers (the
    rule's log file and stderr); an interrupt is left to Python's own hook."""
    if issubclass(kind, KeyboardInterrupt):
        sys.__excepthook__(kind, error, trace)
        return
    logging.getLogger("hybridfmu").critical("the job failed: %s: %s", kind.__name__, error,
                                            exc_info=(kind, error, trace))


class Progress:
    """Periodic progress lines: ``<label>: 40/100 units (40%), 12.3 units/s, 4.9 s left``.

    Args:
        total: amount of work in ``unit`` (e.g. simulated seconds, steps).
        label: what is being done.
        unit: name of the unit of ``total``.
        logger: where the lines go.
        interval_s: minimum wall time between two lines.
    """

    def __init__(self, total: float, label: str, unit: str = "steps",
                 logger: logging.Logger | None = None, interval_s: float = 5.0) -> None:
        self.total = float(total)
        self.label = label
        self.unit = unit
        self.logger = logger or logging.getLogger("hybridfmu.progress")
        self.interval_s = interval_s
        self.done = 0.0
        self._start = time.perf_counter()
        self._last = self._start

    def update(self, amount: float = 1.0) -> None:
        """Add ``amount`` of finished work; log a line when ``interval_s`` has passed."""
        self.done += amount
        now = time.perf_counter()
        if now - self._last >= self.interval_s:
            self._last = now
            self.logger.info(self.line(now))

    def finish(self) -> None:
        """Log the final line (total work and mean rate)."""
        self.logger.info(self.line(time.perf_counter(), final=True))

    def line(self, now: float, final: bool = False) -> str:
        elapsed_s = max(now - self._start, 1e-9)
        rate = self.done / elapsed_s
        if final:
            return f"{self.label}: done {self.done:.4g} {self.unit} in {elapsed_s:.1f} s ({rate:.4g} {self.unit}/s)"
        left_s = (self.total - self.done) / rate if rate > 0 else float("inf")
        percent = 100.0 * self.done / self.total if self.total > 0 else 100.0
        return (f"{self.label}: {self.done:.4g}/{self.total:.4g} {self.unit} ({percent:.0f}%), "
                f"{rate:.4g} {self.unit}/s, {left_s:.1f} s left")
