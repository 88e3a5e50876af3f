# Shared definitions for all rule files: validated config, case roles, case paths, default targets.
from hybridfmu.case import check_case
from hybridfmu.config import validate_case_config

CONFIG_FILE = str((workflow.config_settings.configfiles or ["config/config.yaml"])[-1])
validate_case_config(config)
# Roles against the FMU's interface and every unit, before any job runs: a ConfigError here names the
# config file and the field (an FMU variable that does not exist, a unit of the wrong dimension ...).
ROLES = check_case(config, CONFIG_FILE)

CASE = config["case"]
RESULTS = f"{config.get('results_dir', 'results')}/{CASE}"
MANEUVERS = list(config["maneuvers"])
ALL_TARGETS = []


def fmu_path():
    """Path (str) of the case's FMU: {RESULTS}/fmu/<model_name>.fmu when built, else config fmu.path."""
    if config["fmu"]["source"] == "build":
        return f"{RESULTS}/fmu/{config['fmu']['model_name']}.fmu"
    return config["fmu"]["path"]

