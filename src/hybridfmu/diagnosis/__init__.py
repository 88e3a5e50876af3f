"""Diagnosis of the sim-to-real gap: where it lies, which unmodelled effect causes it, how far it shrinks.

The core knows no machine: it works on the case's roles (measured/unmeasured states, inputs, signals
with units and labels) and any Model-Exchange FMU. Modules: ``problem`` (the case in roles, settings),
``derivatives`` (weak-form derivatives and kernels), ``residual`` (equation error per state),
``prepare`` (ingested maneuvers -> equation error and fitting data), ``effects`` (the effect interface),
``library`` (candidate effects over roles), ``selection`` (fitting, sparse selection, uncertainty),
``regions`` (residual over operating regions and time), ``corrected_model`` (chosen effects added to the
model, open-loop re-simulation), ``export`` (the diagnosed model the later stages load), ``report``
(diagnosis.json, report.md, MLflow), ``figures``, ``inputs`` (a case's inputs from files or frames),
``open_loop`` (the held-out check and the error growth), ``run`` (``analyse``, ``run_diagnosis``). The diagnosis
imports no training or evaluation module: the hybrid model is built on it (:mod:`hybridfmu.model.physics`),
and the trained neural FMU is compared with it afterwards (:mod:`hybridfmu.evaluation.neural_comparison`). The
withheld-effect check, which drives the emulated bench and scores against its truth, is a package of its
own (:mod:`hybridfmu_bench.withheld`): no module here imports the bench. Case plugins with machine knowledge
live in modules named after the machine (``effects_motor``) and are loaded only when a case config lists
them in ``diagnosis.plugins``.
"""
