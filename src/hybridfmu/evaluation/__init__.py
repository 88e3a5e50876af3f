"""Evaluation of the neural FMU against the FMU on held-out maneuvers.

Modules: ``metrics`` (error measures, improvement factors), ``zoom`` (choice of the zoomed
intervals), ``comparison`` (per-role metrics on whole maneuvers and zooms), ``baseline`` (FMU open
loop over whole maneuvers), ``offset`` (the time offset between data and model, paper Fig. 6),
``best`` (the best trial from ``hpo/best.json``), ``evaluate`` (best neural FMU open loop and the
metrics files), ``history`` (the per-trial histories of the search), ``figures`` (the paper's
figures, training curves, Hyperband overview), ``plots`` (every figure of the rule ``plot``),
``report`` (report.md), ``tracking`` (the evaluation's MLflow run), ``learned_correction`` and
``neural_comparison`` (the trained neural FMU beside the diagnosis: what its ANN learned and which diagnosed
effect explains it, rule ``compare_neural_fmu``).
"""
