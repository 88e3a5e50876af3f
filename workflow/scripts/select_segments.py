"""Rule select_segments: the informative spans of one ingested maneuver (JSON) and their plot."""

from hybridfmu.api.stages import select_segments_to_files, setup_rule_logging

setup_rule_logging(snakemake.log[0])
select_segments_to_files(snakemake.input.data, snakemake.output.segments, snakemake.output.plot,
                         snakemake.wildcards.maneuver, dict(snakemake.params.config))
