"""Rule withheld_summary: compare the withheld cases' diagnoses with their ground truth."""

from hybridfmu.diagnosis.withheld import summarise
from hybridfmu.progress import setup_rule_logging

setup_rule_logging(snakemake.log[0])
summarise(list(snakemake.params.cases), list(snakemake.input.diagnoses), list(snakemake.input.truths),
          snakemake.output.csv, snakemake.output.confusion, snakemake.output.markdown,
          expected=dict(snakemake.params.expected))
