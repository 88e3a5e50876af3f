"""Rule hpo_plan: the search plan (brackets, rungs, configurations) and the MLflow parent run."""

from hybridfmu.case import case_roles
from hybridfmu.progress import setup_rule_logging
from hybridfmu.training.hpo import plan_search

setup_rule_logging(snakemake.log[0])
plan_search(
    case=snakemake.params.case,
    seed=snakemake.params.seed,
    hpo_config=snakemake.params.hpo,
    training_config=snakemake.params.training,
    model_config=snakemake.params.model,
    plan_path=snakemake.output.plan,
    tracking_uri=snakemake.params.tracking_uri,
    experiment=snakemake.params.experiment,
    roles=case_roles(snakemake.params.case_sections),
)
