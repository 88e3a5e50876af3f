"""The same numbers on every x86-64 machine: the math libraries' kernel choice pinned for the workflow's jobs.

PyTorch, Intel MKL (PyTorch's BLAS) and OpenBLAS (NumPy's and SciPy's) each pick their kernels from the
processor they run on (AVX-512 here, AVX2 there) and round differently in each. A training run amplifies
those last-bit differences until two machines choose other hyperparameter configurations from the same
config and seed. The workflow therefore starts every job with the kernel choice fixed:

- ``ATEN_CPU_CAPABILITY=avx2``: PyTorch's vectorised kernels at the AVX2 level (every x86-64 server since 2013);
- ``MKL_CBWR=COMPATIBLE``: MKL's conditional numerical reproducibility, the code path that gives the same
  results on every x86 processor, Intel or not;
- ``OPENBLAS_CORETYPE=Haswell``: OpenBLAS' AVX2 kernels whatever the processor.

The math libraries' own thread pools get one thread each: OpenBLAS splits a solve differently over two
threads than over one and rounds differently too. PyTorch's intra-op threads stay the job's (the rule's
``threads``): the reductions of the small tensors used here do not depend on them. ``tests/test_numerics.py``
checks both bit for bit.

The variables only act when set before the libraries load, so they are set in the environment of the
Snakemake process (the Snakefile) and inherited by every job it starts, locally or on a cluster. Snakemake
sets the thread variables of a job to the rule's ``threads``; a rule that uses its threads as processes (the
diagnosis) keeps each process' math libraries at one thread with :func:`one_math_thread`.
"""

from __future__ import annotations

import contextlib
import os
from typing import Iterator, Mapping, MutableMapping

from threadpoolctl import threadpool_limits

#: Environment variable -> value that fixes one math library's kernel choice (see the module docstring).
PINNED_KERNELS: dict[str, str] = {
    "ATEN_CPU_CAPABILITY": "avx2",
    "MKL_CBWR": "COMPATIBLE",
    "OPENBLAS_CORETYPE": "Haswell",
}

#: Thread-count variables of the math libraries' own pools, each pinned to one thread (the jobs set PyTorch's
#: intra-op threads themselves).
THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")


def pinned_environment(environ: Mapping[str, str]) -> dict[str, str]:
    """A copy of ``environ`` with the kernel choice of :data:`PINNED_KERNELS` and one thread for every math
    library's own pool (:data:`THREAD_VARIABLES`); everything else as it was."""
    pinned = dict(environ)
    pinned.update(PINNED_KERNELS)
    pinned.update({name: "1" for name in THREAD_VARIABLES})
    return pinned


def pin_process_environment(environ: MutableMapping[str, str] | None = None) -> dict[str, str]:
    """Set the pinned kernel choice and thread pools in ``environ`` (default ``os.environ``), for the processes
    started from here on. Returns the variables set."""
    environ = os.environ if environ is None else environ
    pinned = pinned_environment(environ)
    changed = {name: pinned[name] for name in (*PINNED_KERNELS, *THREAD_VARIABLES)}
    environ.update(changed)
    return changed


def describe_numerics(environ: Mapping[str, str] | None = None) -> str:
    """One line naming the kernel-choice and thread variables of ``environ`` (default ``os.environ``), for a
    job's log: ``numerics: ATEN_CPU_CAPABILITY=avx2, MKL_CBWR=COMPATIBLE, ...`` (``unset`` where missing)."""
    environ = os.environ if environ is None else environ
    return "numerics: " + ", ".join(f"{name}={environ.get(name, 'unset')}"
                                    for name in (*PINNED_KERNELS, *THREAD_VARIABLES))


@contextlib.contextmanager
def one_math_thread() -> Iterator[None]:
    """Within the block, the loaded math libraries' thread pools (OpenBLAS, MKL, OpenMP) use one thread,
    whatever their variables say; restored afterwards (processes forked within inherit the limit)."""
    with threadpool_limits(limits=1):
        yield
