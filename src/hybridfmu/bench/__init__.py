"""Test-bench emulator: the demo's "real hardware" whose MDF4 logs the workflow learns from.

Modules: ``parameters`` (nominal and true motor parameters), ``hydraulics`` (ball screw, piston,
pressure-volume curve), ``supply``, ``effects`` (catalog of unmodelled effects with a registry),
``plant`` (motor + mechanics + hydraulics, RK4 sub-steps), ``sensors``, ``controller`` (10 kHz
cascade), ``maneuvers`` (segments -> references, spread checks), ``settings`` (the ``bench``
config section), ``mdf_writer`` (MDF4 output) and ``emulate`` (the entry point
:func:`emulate_bench`).
"""

from .effects import EFFECTS, Effect, register_effect
from .emulate import emulate_bench, run_maneuver, summarize_bench
from .settings import parse_bench_settings

__all__ = ["EFFECTS", "Effect", "register_effect", "emulate_bench", "run_maneuver", "summarize_bench",
           "parse_bench_settings"]
