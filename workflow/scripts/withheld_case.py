"""Rule withheld_case: the config of one withheld-effect case, derived from the main case, and its draw record."""

from hybridfmu_bench.withheld.suite import write_case_config
from hybridfmu.api.stages import setup_rule_logging

setup_rule_logging(snakemake.log[0])
write_case_config(dict(snakemake.params.config), snakemake.wildcards.wcase, snakemake.input.fmu,
                  snakemake.output.case, draw_path=snakemake.output.draw, duration_s=snakemake.params.duration_s)
