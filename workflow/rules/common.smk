# Shared definitions for all rule files: validated config, case paths, default targets.
from hybridfmu.config import validate_case_config

validate_case_config(config)

CASE = config["case"]
RESULTS = f"{config.get('results_dir', 'results')}/{CASE}"
MANEUVERS = list(config["maneuvers"])
ALL_TARGETS = []
