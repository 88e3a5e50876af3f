"""Diagnosis of the sim-to-real gap: where it lies, which unmodelled effect causes it, how far it shrinks.

Modules: ``derivatives`` (weak-form derivatives and kernels), ``residual`` (equation error per
state), ``layout`` (where the motor's quantities sit in the model), ``prepare`` (measured
maneuvers -> equation error and fitting data), ``effects`` (candidate-effect library),
``selection`` (fitting, sparse selection, uncertainty, stability), ``regions`` (residual over
operating regions and time), ``corrected_model`` (chosen effects as explicit corrections,
open-loop re-simulation), ``report`` (diagnosis.json, report.md, figures), ``run`` (the
``diagnose`` entry point), ``withheld`` (the withheld-effect check), ``synthetic`` (a NumPy
model of the equations and synthetic trajectories for tests).
"""
