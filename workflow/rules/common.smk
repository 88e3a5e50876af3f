# Shared definitions for all rule files: validated config, case roles, case paths, default targets.
from hybridfmu.case_checks import check_case
from hybridfmu.config import validate_case_config

CONFIG_FILE = str((workflow.config_settings.configfiles or ["config/config.yaml"])[-1])
# The config file read again strictly (Snakemake's YAML reading keeps the last of a key listed twice without a
# word) and the config checked against the schema: a ConfigError names the file, the line or field, the key.
from hybridfmu.config import check_config_file
check_config_file(CONFIG_FILE, config)
validate_case_config(config)
# The math libraries' kernel choice fixed for every job started from here (inherited environment), so that the
# same config and seed give the same numbers on any x86-64 machine (hybridfmu.numerics; config.pin_kernels).
if config.get("pin_kernels", True):
    from hybridfmu.numerics import pin_process_environment
    pin_process_environment()
# Roles against the FMU's interface and every unit, before any job runs: a ConfigError here names the
# config file and the field (an FMU variable that does not exist, a unit of the wrong dimension ...).
ROLES = check_case(config, CONFIG_FILE)
# The MLflow store before any job runs (seconds; creates nothing, so dry runs stay clean): a ConfigError
# names the config file, config.mlflow.tracking_uri, the URI and why. On SIGINT, Snakemake passes SIGINT
# on to its jobs (else running jobs finish first and are then redone as incomplete).
from hybridfmu.tracking import check_tracking_store, tracking_uri as _tracking_uri
from hybridfmu.tracking.jobs import forward_interrupt
check_tracking_store(_tracking_uri(config.get("mlflow"), config.get("results_dir", "results")), CONFIG_FILE,
                     timeout_s=float(config.get("mlflow", {}).get("request_timeout_s", 10.0)))
forward_interrupt()
# What a valid config leaves out (no test maneuver: the held-out check is not run), logged as the run starts.
from hybridfmu.case_checks import case_warnings
from snakemake.logging import logger as _logger
for _warning in case_warnings(config, CONFIG_FILE):
    _logger.warning(f"Warning: {_warning}")

CASE = config["case"]
RESULTS = f"{config.get('results_dir', 'results')}/{CASE}"
MANEUVERS = list(config["maneuvers"])
# a hybrid (model.physics_terms): a second search (train.smk) and a fourth model in the evaluation
from hybridfmu.model.settings import uses_physics
HYBRID = uses_physics(config.get("model") or {})
# the hybrid search's physical layer (ANN at zero): rolled out once for its rung 0, a candidate of its final choice
# (train.smk), and the FMU + diagnosed effects of the closed-loop evaluation (evaluate.smk)
PHYSICAL_LAYER_ROLLOUT = f"{RESULTS}/hybrid/physical_layer_rollout.pt"
PHYSICAL_LAYER_CHECKPOINT = f"{RESULTS}/hybrid/physical_layer.pt"
# a hybrid whose delays start at the time-offset stage's estimates gets its own, on its physical layer (rule
# hybrid_time_offset in train.smk; the report and the summary show them beside its delays)
from hybridfmu.data.settings import section_settings as _section_settings
HYBRID_TIME_OFFSET = ([f"{RESULTS}/hybrid/time_offset.json"] if HYBRID and _section_settings(
    config.get("model"), "model")["input_delay"]["init_s"] == "time_offset" else [])
ALL_TARGETS = []

# Scheduling only (no result depends on the order jobs run in): the hybrid's chain (the diagnosis, the time offsets
# on its physical layer, its search) is the workflow's longest; its jobs go first when a core is free, so that it
# runs beside the neural FMU's search rather than after it, and the ceiling's simulations, which only the final
# evaluation reads, fill the gaps.
HYBRID_CHAIN_PRIORITY = 1
CEILING_PRIORITY = -1


def search_priority(wildcards):
    """A search's jobs' priority: the hybrid's chain first (see HYBRID_CHAIN_PRIORITY)."""
    return HYBRID_CHAIN_PRIORITY if wildcards.search == "hybrid" else 0



def config_sections(*names):
    """The named top-level sections of the case config (those present), for a rule's params: a job
    reruns when a section it reads changes, and only then; every rule's params name the sections its
    script or the functions it calls read. Of ``mlflow`` only the destination counts (mlflow_destination)."""
    return {name: mlflow_destination() if name == "mlflow" else config[name] for name in names if name in config}


def mlflow_destination():
    """Where a stage records its MLflow run (config.mlflow.tracking_uri and .experiment): a new destination
    reruns the stages that log runs; the retry and timeout settings (hybridfmu.tracking.retry_settings) are
    read from the config when a training job runs, and a change of them reruns nothing."""
    mlflow = config.get("mlflow", {})
    return {key: mlflow.get(key, "") for key in ("tracking_uri", "experiment")}


def fmu_interface():
    """What of config.fmu locates the FMU's interface (names and declared units), without its parameters."""
    return {key: config["fmu"].get(key) for key in ("source", "model_name", "path")}


def fmu_path():
    """Path (str) of the case's FMU (hybridfmu.config.case_fmu_path)."""
    from hybridfmu.config import case_fmu_path

    return str(case_fmu_path(config))

