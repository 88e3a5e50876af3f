"""The workflow's stages as Python functions: what each Snakemake rule calls, importable one by one.

Every script in ``workflow/scripts/`` takes its functions from here (``tests/test_workflow_graph.py`` checks it),
so a single stage can be rerun from Python with the same call the rule makes, on the files the rule names. A
function is imported on first use: a rule's job loads only its own stage's modules.

| rule(s) | function(s) |
|---|---|
| every rule | ``setup_rule_logging`` (the rule's log file, progress lines) |
| build_fmu | ``build_fmu`` |
| choose_grid, ingest | ``choose_grid``, ``ingest_to_parquet``, ``grid_rate_hz``, ``chosen_conventions`` |
| select_segments | ``select_segments_to_files`` |
| calibrate | ``run_calibration`` |
| simulate_baseline | ``run_baseline`` |
| time_offset, hybrid_time_offset | ``run_time_offset``, ``run_hybrid_time_offset`` |
| diagnose | ``diagnose`` |
| hpo_prepare, hpo_plan | ``prepare_training_data``, ``plan_search`` |
| train_rung, hpo_select_rung, hpo_select_best | ``run_trial_rung``, ``select_rung``, ``select_best``, ``catch_up_search`` |
| physical layer of the hybrid | ``run_physical_layer_rollout``, ``write_physical_layer_checkpoint`` |
| finalists | ``score_candidate``, ``choose_among_candidates`` |
| simulate_best, evaluate | ``simulate_best``, ``run_evaluation`` |
| simulate_closed_loop | ``closed_loop_model``, ``closed_loop_settings``, ``write_closed_loop`` |
| compare_neural_fmu, plot, report, summary | ``compare_neural_fmu``, ``draw_all``, ``write_report``, ``write_case_summary`` |
| export | ``export_model`` |
| robustness_seed, robustness_summary | ``run_seed``, ``seed_wall_times``, ``seed_job_counts``, ``write_summary`` |
| (helpers the rules share) | ``case_roles``, ``read_json``, ``retry_settings``, ``tracking_uri``, ``bound_http_requests``, ``job_guard`` |
"""

from __future__ import annotations

import importlib
from typing import Any

#: Function name -> the module that defines it.
STAGES: dict[str, str] = {
    "setup_rule_logging": "hybridfmu.progress",
    "build_fmu": "hybridfmu.fmu.build",
    "choose_grid": "hybridfmu.data.ingest",
    "ingest_to_parquet": "hybridfmu.data.ingest",
    "grid_rate_hz": "hybridfmu.data.grid",
    "chosen_conventions": "hybridfmu.data.grid",
    "select_segments_to_files": "hybridfmu.data.segments_stage",
    "run_calibration": "hybridfmu.calibration",
    "run_baseline": "hybridfmu.evaluation.baseline",
    "run_time_offset": "hybridfmu.evaluation.offset",
    "run_hybrid_time_offset": "hybridfmu.evaluation.hybrid_offset",
    "diagnose": "hybridfmu.diagnosis.report",
    "prepare_training_data": "hybridfmu.training.hpo",
    "plan_search": "hybridfmu.training.hpo",
    "run_trial_rung": "hybridfmu.training.trial",
    "select_rung": "hybridfmu.training.hpo",
    "select_best": "hybridfmu.training.hpo",
    "catch_up_search": "hybridfmu.training.search_tracking",
    "run_physical_layer_rollout": "hybridfmu.training.trial",
    "write_physical_layer_checkpoint": "hybridfmu.training.finalists",
    "score_candidate": "hybridfmu.training.finalists",
    "choose_among_candidates": "hybridfmu.training.finalists",
    "simulate_best": "hybridfmu.evaluation.evaluate",
    "run_evaluation": "hybridfmu.evaluation.evaluate",
    "closed_loop_model": "hybridfmu.evaluation.closed_loop",
    "closed_loop_settings": "hybridfmu.evaluation.closed_loop",
    "write_closed_loop": "hybridfmu.evaluation.closed_loop",
    "compare_neural_fmu": "hybridfmu.evaluation.neural_comparison",
    "draw_all": "hybridfmu.evaluation.plots",
    "write_report": "hybridfmu.evaluation.report",
    "write_case_summary": "hybridfmu.evaluation.summary",
    "export_model": "hybridfmu.export.stage",
    "run_seed": "hybridfmu.evaluation.robustness",
    "seed_wall_times": "hybridfmu.evaluation.robustness",
    "seed_job_counts": "hybridfmu.evaluation.robustness",
    "write_summary": "hybridfmu.evaluation.robustness",
    "case_roles": "hybridfmu.data.roles",
    "read_json": "hybridfmu.io",
    "retry_settings": "hybridfmu.tracking",
    "tracking_uri": "hybridfmu.tracking",
    "bound_http_requests": "hybridfmu.tracking.mlflow_store",
    "job_guard": "hybridfmu.tracking.jobs",
}

__all__ = sorted(STAGES)


def __getattr__(name: str) -> Any:
    """The stage function ``name``, imported from its module on first use."""
    module = STAGES.get(name)
    if module is None:
        raise AttributeError(f"hybridfmu.api.stages has no stage {name!r}; the stages are: {', '.join(__all__)}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return __all__
