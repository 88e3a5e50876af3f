"""Rule select_best: the best configuration over all brackets -> hpo/best.json (by the objective, or the finalist
rule score_finalists chose over whole maneuvers).

Rungs whose MLflow logging failed are logged first (the queue beside the plan), runs that killed jobs left
RUNNING are ended, and best.json names the best trial's MLflow run even when it was logged late.
"""

from hybridfmu.api.stages import catch_up_search, retry_settings, select_best, setup_rule_logging

setup_rule_logging(snakemake.log[0])
settings = retry_settings(snakemake.config.get("mlflow"))
catch_up_search(snakemake.input.plan, settings)
record = select_best(
    plan_path=snakemake.input.plan,
    selection_paths=list(snakemake.input.selections),
    best_path=snakemake.output.best,
    best_model_path=snakemake.output.model,
    summary_path=snakemake.output.summary,
    case=snakemake.params.case,
    finalists_path=snakemake.input.finalists[0] if snakemake.input.finalists else None,
)
catch_up_search(snakemake.input.plan, settings, best_path=snakemake.output.best)
