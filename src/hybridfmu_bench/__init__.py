"""Test-bench emulator: the demo's "real hardware" whose MDF4 logs the workflow learns from.

A package of its own beside the tool (``hybridfmu``): the bench holds the ground truth, so it may import the
tool, and the tool never imports it (tests/test_import_structure.py). Its subpackage ``withheld`` is the
withheld-effect suite, which drives the bench and scores the diagnosis against its truth. The workflow reaches
the bench only through its own rules (emulation, the ceiling, the withheld suite) and through the demo's
declared controller (``ecu``: the control software a user has).

Modules: ``parameters`` (nominal and true motor parameters), ``hydraulics`` (ball screw, piston,
pressure-volume curve), ``supply``, ``effects`` (catalog of unmodelled effects with a registry),
``plant`` (motor + mechanics + hydraulics, RK4 sub-steps), ``sensors``, ``controller`` (10 kHz
cascade), ``maneuvers`` (segments -> references, spread checks), ``settings`` (the ``bench``
config section), ``mdf_writer`` (MDF4 output) and ``emulate`` (the entry point
:func:`emulate_bench`); ``ecu`` (the controller as the control software a user has) and ``ceiling``
(the true plant open loop, for scoring only).
"""

from .effects import EFFECTS, Effect, register_effect
from .emulate import emulate_bench, run_maneuver, summarize_bench
from .settings import parse_bench_settings

__all__ = ["EFFECTS", "Effect", "register_effect", "emulate_bench", "run_maneuver", "summarize_bench",
           "parse_bench_settings"]
