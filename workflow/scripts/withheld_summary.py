"""Rule withheld_summary: score the withheld cases' diagnoses against their ground truth and aggregate."""

from hybridfmu_bench.withheld.report import summarise
from hybridfmu.api.stages import setup_rule_logging

setup_rule_logging(snakemake.log[0])
summarise(list(snakemake.params.cases), list(snakemake.input.diagnoses), list(snakemake.input.truths),
          list(snakemake.input.draws), snakemake.output.csv, snakemake.output.confusion, snakemake.output.detection,
          snakemake.output.markdown, expected=dict(snakemake.params.expected), targets=dict(snakemake.params.targets),
          background=dict(snakemake.params.background),
          calibration_seeds=None if snakemake.params.calibration_seeds is None else list(snakemake.params.calibration_seeds),
          headline_path=snakemake.output.headline)
