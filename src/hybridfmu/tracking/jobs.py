"""Liveness of the workflow's jobs (Linux ``/proc``): who owns a running job, whether it is still alive, and
what a job does when the Snakemake process that started it is gone.

- A job's *owner* is its nearest ancestor that is a Snakemake process (``snakemake`` or ``python -m
  snakemake``). Processes are identified by PID and start time (``/proc/<pid>/stat`` field 22), so a
  reused PID is not mistaken for the original process.
- :func:`start_watchdog`: a daemon thread that stops the job when its owner is gone (``kill -9`` of
  Snakemake leaves the job running as an orphan otherwise, while ``--rerun-incomplete`` starts it again).
- :class:`OutputLock`: one job per output; a job that starts for an output whose earlier job is an orphan
  still running stops that orphan first (the lock file records its PID).
- :func:`forward_interrupt`: on SIGINT the Snakemake process passes SIGINT on to its jobs (as Ctrl-C in a
  terminal does for the whole process group); Snakemake's local executor otherwise waits for running jobs
  to end and then marks their outputs incomplete.
- :func:`owner_tags` / :func:`owner_alive`: the MLflow tags that record which process writes a run, and
  whether it still runs (runs left RUNNING by dead jobs are ended by ``search.end_stale_runs``).

Cluster jobs (Snakemake's Slurm executor, ``workflow/profiles/slurm``): a job's script runs under a Snakemake
process of its own (``--mode remote``: the batch job's Snakemake, which starts the job step's Snakemake with
``srun``), not under the workflow's Snakemake process, which runs on the submitting host and is not an ancestor.
The watchdog then watches the job step's Snakemake (when it is gone, so is the job's allocation); Slurm itself
stops the job on ``scancel`` or at its time limit. :func:`workflow_process` is None in such a job: whoever needs
the workflow's process (the search's parent run) records no PID then. Runs and output locks also record the
Slurm job (``SLURM_JOB_ID``); a run written on another node counts as ended once ``squeue`` reports its job
finished (:func:`slurm_job_state`).
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import logging
import os
import signal
import socket
import subprocess
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator

LOG = logging.getLogger(__name__)

#: Exit status of a job stopped because its Snakemake process is gone or interrupted it.
STOPPED_EXIT_CODE = 75


@dataclass(frozen=True)
class ProcessId:
    """A process: PID and start time (clock ticks since boot), which tell a reused PID apart."""

    pid: int
    start: int

    def alive(self) -> bool:
        return process_start(self.pid) == self.start


def _stat_fields(pid: int) -> list[str] | None:
    """Fields of ``/proc/<pid>/stat`` after the command name (index 0 = state), or None."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except (FileNotFoundError, ProcessLookupError, PermissionError, OSError):
        return None
    return text[text.rfind(")") + 2:].split()


def process_start(pid: int) -> int | None:
    """Start time of a live process (not a zombie), or None if there is no such live process."""
    fields = _stat_fields(pid)
    if fields is None or fields[0] in ("Z", "X", "x"):
        return None
    return int(fields[19])


def parent_pid(pid: int) -> int | None:
    fields = _stat_fields(pid)
    return int(fields[1]) if fields else None


def process_args(pid: int) -> list[str]:
    try:
        raw = Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return []
    return [part.decode(errors="replace") for part in raw.split(b"\0") if part]


def is_snakemake(args: list[str]) -> bool:
    """Whether a command line runs Snakemake itself (not a job script under ``.snakemake/scripts``)."""
    for index, arg in enumerate(args[:3]):
        if os.path.basename(arg) == "snakemake":
            return True
        if arg == "-m" and index + 1 < len(args) and args[index + 1] == "snakemake":
            return True
    return False


def runs_remote_jobs(args: list[str]) -> bool:
    """Whether a Snakemake command line runs jobs handed to it by another Snakemake process (``--mode remote``:
    a cluster job's Snakemake) instead of being the workflow's own process."""
    for index, arg in enumerate(args):
        if arg == "--mode" and index + 1 < len(args) and args[index + 1] == "remote":
            return True
        if arg == "--mode=remote":
            return True
    return False


def snakemake_ancestor(pid: int | None = None) -> ProcessId | None:
    """The nearest ancestor of ``pid`` (default: this process) that is a Snakemake process, or None."""
    current = parent_pid(pid or os.getpid())
    while current and current > 1:
        if is_snakemake(process_args(current)):
            start = process_start(current)
            return ProcessId(current, start) if start is not None else None
        current = parent_pid(current)
    return None


def workflow_process(pid: int | None = None) -> ProcessId | None:
    """The workflow's own Snakemake process when it is an ancestor of ``pid`` (default: this process): the
    nearest Snakemake ancestor unless that one runs remote jobs (a cluster job: the workflow's process runs
    on the submitting host, out of sight), else None."""
    current = parent_pid(pid or os.getpid())
    while current and current > 1:
        args = process_args(current)
        if is_snakemake(args):
            if runs_remote_jobs(args):
                return None
            start = process_start(current)
            return ProcessId(current, start) if start is not None else None
        current = parent_pid(current)
    return None


def slurm_job_id() -> str:
    """The Slurm job this process runs in (``SLURM_JOB_ID``), or ""."""
    return os.environ.get("SLURM_JOB_ID", "")


#: Slurm job states of a job whose processes may still run.
SLURM_ACTIVE_STATES = frozenset({"PENDING", "CONFIGURING", "RUNNING", "COMPLETING", "SUSPENDED", "REQUEUED",
                                 "REQUEUE_FED", "REQUEUE_HOLD", "RESIZING", "SIGNALING", "STAGE_OUT", "STOPPED"})


def slurm_job_state(job_id: str, timeout_s: float = 10.0) -> str | None:
    """State of a Slurm job as ``squeue`` reports it (RUNNING, COMPLETED, ...), or None when unknown (no
    squeue, no answer, or the job no longer known to the controller)."""
    if not job_id:
        return None
    try:
        done = subprocess.run(["squeue", f"--jobs={job_id}", "--noheader", "--states=all", "--format=%T"],
                              capture_output=True, text=True, timeout=timeout_s)
    except (OSError, subprocess.TimeoutExpired):
        return None
    states = done.stdout.split()
    return states[0] if done.returncode == 0 and states else None


def this_process() -> ProcessId:
    return ProcessId(os.getpid(), process_start(os.getpid()) or 0)


def descendants(pid: int) -> list[int]:
    """PIDs of every live descendant of ``pid`` (children first)."""
    children: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            parent = parent_pid(int(entry.name))
            if parent is not None:
                children.setdefault(parent, []).append(int(entry.name))
    found, queue = [], list(children.get(pid, []))
    while queue:
        child = queue.pop(0)
        found.append(child)
        queue.extend(children.get(child, []))
    return found


# --- MLflow owner tags --------------------------------------------------------------------------------

OWNER_TAGS = ("hybridfmu.host", "hybridfmu.pid", "hybridfmu.pid_start", "hybridfmu.snakemake_pid",
              "hybridfmu.snakemake_start", "hybridfmu.slurm_job_id")


def owner_tags() -> dict[str, str]:
    """Tags naming the process that writes an MLflow run (its Snakemake process, if any, and its Slurm job,
    if any)."""
    me, owner = this_process(), snakemake_ancestor()
    return {"hybridfmu.host": socket.gethostname(), "hybridfmu.pid": str(me.pid), "hybridfmu.pid_start": str(me.start),
            "hybridfmu.snakemake_pid": str(owner.pid) if owner else "",
            "hybridfmu.snakemake_start": str(owner.start) if owner else "",
            "hybridfmu.slurm_job_id": slurm_job_id()}


def owner_alive(tags: dict[str, str]) -> bool | None:
    """Whether the process recorded by :func:`owner_tags` still runs: None when unknown (no such tags, or a
    run written on another host whose Slurm job, if any, ``squeue`` does not report as finished)."""
    if tags.get("hybridfmu.host") != socket.gethostname() and tags.get("hybridfmu.slurm_job_id") \
            and tags.get("hybridfmu.pid"):
        state = slurm_job_state(tags["hybridfmu.slurm_job_id"])
        return None if state is None else state in SLURM_ACTIVE_STATES
    if tags.get("hybridfmu.host") != socket.gethostname() or not tags.get("hybridfmu.pid"):
        return None
    try:
        process = ProcessId(int(tags["hybridfmu.pid"]), int(tags.get("hybridfmu.pid_start") or 0))
    except ValueError:
        return None
    return process.alive()


# --- watchdog -----------------------------------------------------------------------------------------

def start_watchdog(label: str, interval_s: float = 1.0, grace_s: float = 10.0,
                   owner: ProcessId | None = None,
                   on_stop: Callable[[], None] | None = None) -> threading.Thread | None:
    """Stop this job when its Snakemake process (``owner``, default: the nearest Snakemake ancestor) is gone.

    A daemon thread polls the owner every ``interval_s``; once it is gone the thread logs one line naming
    ``label``, interrupts the main thread (KeyboardInterrupt: temporary files of atomic writes are removed)
    and, if the job has not ended ``grace_s`` later, ends the process with exit status
    :data:`STOPPED_EXIT_CODE`. Returns the thread, or None when the job has no Snakemake ancestor. In a Slurm
    job the owner is the job step's Snakemake process (see the module's docstring).
    """
    import _thread

    owner = owner or snakemake_ancestor()
    if owner is None:
        return None

    def watch() -> None:
        while owner.alive():
            time.sleep(interval_s)
        LOG.error("%s: the Snakemake process (PID %d) that started this job is gone; stopping the job "
                  "(a rerun with --rerun-incomplete redoes it)", label, owner.pid)
        if on_stop is not None:
            with contextlib.suppress(Exception):
                on_stop()
        _thread.interrupt_main()
        time.sleep(grace_s)
        os._exit(STOPPED_EXIT_CODE)

    thread = threading.Thread(target=watch, name="snakemake-watchdog", daemon=True)
    thread.start()
    return thread


# --- per-output lock ----------------------------------------------------------------------------------

class OutputLockError(RuntimeError):
    """Another live job of a live Snakemake process produces the same output."""


class OutputLock:
    """Exclusive lock of one job's output (file ``lock_path``, holding the PID of the job that writes it).

    ``acquire``: if a previous job still holds the lock, it is an orphan when its Snakemake process is gone:
    it is stopped (SIGTERM, then SIGKILL after ``grace_s``) and the lock taken over. A holder whose
    Snakemake process is alive is another workflow's job: :class:`OutputLockError` (names the lock file and
    both PIDs).
    """

    def __init__(self, lock_path: str | Path, grace_s: float = 10.0) -> None:
        self.path = Path(lock_path)
        self.grace_s = grace_s
        self._handle: Any = None

    def _holder(self) -> dict[str, Any]:
        try:
            return json.loads(self.path.read_text() or "{}")
        except (OSError, json.JSONDecodeError):
            return {}

    def acquire(self, timeout_s: float = 60.0) -> dict[str, Any] | None:
        """Take the lock; returns the record of an orphan that was stopped, else None."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        handle = open(self.path, "a+")
        stopped = None
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                pass
            holder = self._holder()
            if holder and stopped is None:
                stopped = self._stop_orphan(holder)
            if time.monotonic() > deadline:
                handle.close()
                raise OutputLockError(f"{self.path}: still locked by PID {holder.get('pid')}{_where(holder)} after "
                                      f"{timeout_s:.0f} s")
            time.sleep(0.2)
        me, owner = this_process(), snakemake_ancestor()
        record = {"pid": me.pid, "start": me.start, "host": socket.gethostname(),
                  "snakemake_pid": owner.pid if owner else None, "snakemake_start": owner.start if owner else None,
                  "slurm_job_id": slurm_job_id(), "since": time.strftime("%Y-%m-%dT%H:%M:%S")}
        handle.seek(0)
        handle.truncate()
        handle.write(json.dumps(record) + "\n")
        handle.flush()
        self._handle = handle
        return stopped

    def _stop_orphan(self, holder: dict[str, Any]) -> dict[str, Any]:
        pid, start = holder.get("pid"), holder.get("start")
        if holder.get("host") and holder["host"] != socket.gethostname():
            # another node's job (a cluster job): its PID means nothing here; wait for its lock
            LOG.warning("%s: the output is locked by job PID %s%s; waiting for it", self.path, pid, _where(holder))
            return holder
        job = ProcessId(int(pid), int(start)) if pid and start is not None else None
        if job is None or not job.alive():
            return holder  # the holder ended meanwhile; its lock goes with it
        if holder.get("snakemake_pid"):
            owner = ProcessId(int(holder["snakemake_pid"]), int(holder.get("snakemake_start") or 0))
            mine = snakemake_ancestor()
            if owner.alive() and owner != mine:
                raise OutputLockError(f"{self.path}: the output is being produced by job PID {pid}{_where(holder)} of "
                                      f"the running Snakemake process {owner.pid}; not starting a second job for it")
        LOG.warning("%s: an earlier job (PID %s) for this output is still running without its Snakemake process; "
                    "stopping it and taking over", self.path, pid)
        with contextlib.suppress(ProcessLookupError):
            os.kill(job.pid, signal.SIGTERM)
        deadline = time.monotonic() + self.grace_s
        while job.alive() and time.monotonic() < deadline:
            time.sleep(0.1)
        if job.alive():
            with contextlib.suppress(ProcessLookupError):
                os.kill(job.pid, signal.SIGKILL)
        return holder

    def release(self) -> None:
        if self._handle is not None:
            with contextlib.suppress(OSError):
                fcntl.flock(self._handle, fcntl.LOCK_UN)
            self._handle.close()
            self._handle = None

    def __enter__(self) -> "OutputLock":
        self.acquire()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.release()


def _where(holder: dict[str, Any]) -> str:
    """Host and Slurm job of a lock's holder, for messages (with how to stop a Slurm job)."""
    text = f" on {holder['host']}" if holder.get("host") else ""
    if holder.get("slurm_job_id"):
        text += f" (Slurm job {holder['slurm_job_id']}; `scancel {holder['slurm_job_id']}` stops it)"
    return text


# --- signals ------------------------------------------------------------------------------------------

def interrupt_on_sigterm() -> None:
    """Make SIGTERM raise KeyboardInterrupt in the main thread (default: die at once), so a job that is
    stopped removes the temporary files of its atomic writes."""
    def handler(signum: int, frame: Any) -> None:
        LOG.error("received signal %d; stopping the job", signum)
        raise KeyboardInterrupt(f"signal {signum}")

    signal.signal(signal.SIGTERM, handler)


@contextlib.contextmanager
def job_guard(lock_path: str | Path, label: str, watch: bool = True) -> Iterator[OutputLock]:
    """A workflow job's protection: the output lock (taking over from an orphan), SIGTERM as an interrupt,
    and the watchdog on the Snakemake process."""
    interrupt_on_sigterm()
    lock = OutputLock(lock_path)
    stopped = lock.acquire()
    if stopped:
        LOG.info("%s: took over from the earlier job PID %s", label, stopped.get("pid"))
    if watch:
        start_watchdog(label)
    try:
        yield lock
    finally:
        lock.release()


_FORWARDING_INSTALLED = False


def forward_interrupt() -> bool:
    """In the Snakemake process: on SIGINT, send SIGINT to every job process (descendant) first, then
    interrupt Snakemake as before. Returns whether the handler was installed (only from the main thread)."""
    global _FORWARDING_INSTALLED
    if _FORWARDING_INSTALLED:
        return True
    if threading.current_thread() is not threading.main_thread():
        return False
    previous = signal.getsignal(signal.SIGINT)

    def handler(signum: int, frame: Any) -> None:
        for pid in descendants(os.getpid()):
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.kill(pid, signal.SIGINT)
        if callable(previous):
            previous(signum, frame)
        else:
            raise KeyboardInterrupt

    signal.signal(signal.SIGINT, handler)
    _FORWARDING_INSTALLED = True
    return True
