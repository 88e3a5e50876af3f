"""Rule select_best: the best configuration over all brackets -> hpo/best.json."""

from hybridfmu.progress import setup_rule_logging
from hybridfmu.training.hpo import select_best

setup_rule_logging(snakemake.log[0])
select_best(
    plan_path=snakemake.input.plan,
    selection_paths=list(snakemake.input.selections),
    best_path=snakemake.output.best,
    best_model_path=snakemake.output.model,
    summary_path=snakemake.output.summary,
    case=snakemake.params.case,
)
