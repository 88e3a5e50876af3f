# Shared definitions for all rule files: validated config, case paths, default targets.
from hybridfmu.config import validate_case_config

validate_case_config(config)

CASE = config["case"]
RESULTS = f"{config.get('results_dir', 'results')}/{CASE}"
MANEUVERS = list(config["maneuvers"])
ALL_TARGETS = []


def fmu_path():
    """Path (str) of the case's FMU: {RESULTS}/fmu/<model_name>.fmu when built, else config fmu.path."""
    if config["fmu"]["source"] == "build":
        return f"{RESULTS}/fmu/{config['fmu']['model_name']}.fmu"
    return config["fmu"]["path"]
