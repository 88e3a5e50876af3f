"""Checkpoint rule select_rung: the survivors of one (bracket, rung) by validation objective."""

from hybridfmu.progress import setup_rule_logging
from hybridfmu.training.hpo import select_rung

setup_rule_logging(snakemake.log[0])
select_rung(
    plan_path=snakemake.input.plan,
    bracket=int(snakemake.wildcards.bracket),
    rung=int(snakemake.wildcards.rung),
    result_paths=list(snakemake.input.results),
    selection_path=snakemake.output.selection,
)
