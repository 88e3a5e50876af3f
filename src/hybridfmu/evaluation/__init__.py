"""Evaluation of the neural FMU against the FMU on held-out maneuvers.

Modules: ``metrics`` (error measures, improvement factors), ``zoom`` (choice of the zoomed
intervals), ``baseline`` (FMU open loop over whole maneuvers), ``offset`` (the time offset
between data and model, paper Fig. 6), ``evaluate`` (best model and FMU on validation/test),
``figures`` (the paper's figures, training curves, Hyperband overview), ``history`` (reading
the per-trial training histories), ``report`` (report.md), ``tracking`` (the evaluation's
MLflow run).
"""
