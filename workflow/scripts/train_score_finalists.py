"""Rule score_finalists: a search's final choice among its scored candidates -> {search}/finalists.json."""

from hybridfmu.api.stages import case_roles, choose_among_candidates, setup_rule_logging

setup_rule_logging(snakemake.log[0])
choose_among_candidates(
    candidate_paths=list(snakemake.input.candidates),
    maneuvers=list(snakemake.params.maneuvers),
    top=snakemake.params.top,
    plan_path=snakemake.input.plan,
    roles=case_roles(snakemake.params.case),
    scores_path=snakemake.output.finalists,
)
