"""Rule hpo_plan: the search plan (brackets, rungs, configurations) and the MLflow parent run (runs that
killed jobs left RUNNING in the case's experiment are ended as KILLED first)."""

from hybridfmu.api.stages import (bound_http_requests, case_roles, plan_search, read_json, retry_settings,
                                  setup_rule_logging, tracking_uri)

setup_rule_logging(snakemake.log[0])
settings = retry_settings(snakemake.config.get("mlflow"))
uri = tracking_uri(snakemake.params.mlflow, snakemake.params.results_dir)
if uri.startswith(("http://", "https://")):
    bound_http_requests(settings["request_timeout_s"], settings["http_retries"])
plan_search(
    case=snakemake.params.case,
    seed=snakemake.params.seed,
    hpo_config=snakemake.params.hpo,
    training_config=snakemake.params.training,
    model_config=snakemake.params.model,
    plan_path=snakemake.output.plan,
    tracking_uri=uri,
    experiment=snakemake.params.experiment,
    roles=case_roles(snakemake.params.case_sections),
    time_offset_path=next(iter(snakemake.input.time_offset), None),  # a list input: empty or the summary
    sample_period_s=read_json(snakemake.input.statistics).get("sample_period_s"),
    training_data_s=read_json(snakemake.input.statistics).get("selected_duration_s"),
)
