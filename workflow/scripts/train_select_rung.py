"""Checkpoint rule select_rung: the survivors of one (bracket, rung) by validation objective."""

from hybridfmu.api.stages import select_rung, setup_rule_logging

setup_rule_logging(snakemake.log[0])
select_rung(
    plan_path=snakemake.input.plan,
    bracket=int(snakemake.wildcards.bracket),
    rung=int(snakemake.wildcards.rung),
    result_paths=list(snakemake.input.results),
    selection_path=snakemake.output.selection,
)
