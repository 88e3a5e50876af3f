# The trained models leave the workflow: each as an FMI 2.0 Co-Simulation FMU that embeds the case's FMU
# (rule export, one job per model; hybridfmu.export), replayed with FMPy against the evaluation's trajectories.
from hybridfmu.export.names import EXPORT_MODELS as _ALL_EXPORT_MODELS, fmu_file_name, fmu_file_pattern

EXPORT_DIR = f"{RESULTS}/export"
EXPORT_MODELS = [model for model in _ALL_EXPORT_MODELS if model != "hybrid" or HYBRID]
# the model each export stands for, and the search whose best.json names it (the FMU + effects: the diagnosis)
EXPORT_BEST = {"neural_fmu": [f"{RESULTS}/hpo/best.json"], "hybrid": [f"{RESULTS}/hybrid/best.json"], "fmu_effects": []}
# the maneuvers each exported FMU replays: config export.check_maneuvers, else the first test maneuver (the first
# validation maneuver without one); evaluated maneuvers only (their trajectories are the reference)
EXPORT_CHECK_MANEUVERS = list((config.get("export") or {}).get("check_maneuvers") or [
    next((name for role in ("test", "validation") for name in EVAL_MANEUVERS
          if config["maneuvers"][name]["role"] == role), None)] if EVAL_MANEUVERS else [])
EXPORT_CHECK_MANEUVERS = [name for name in EXPORT_CHECK_MANEUVERS if name]


def exported_fmu(model):
    """Path of the exported FMU of ``model``."""
    return f"{EXPORT_DIR}/{fmu_file_name(CASE, model)}"


if EXPORT_CHECK_MANEUVERS:

    rule export:
        input:
            best=lambda wildcards: EXPORT_BEST[wildcards.model],
            fmu=fmu_path(),
            calibration=CALIBRATION_JSON,
            data=expand(f"{RESULTS}/data/{{maneuver}}.parquet", maneuver=EXPORT_CHECK_MANEUVERS),
            trajectories=expand(f"{RESULTS}/evaluation/trajectories/{{maneuver}}.parquet",
                                maneuver=EXPORT_CHECK_MANEUVERS),
            run=f"{RESULTS}/evaluation/mlflow_run.json",
            diagnosed=lambda wildcards: [DIAGNOSED_MODEL] if wildcards.model != "neural_fmu" else [],
            diagnosis=lambda wildcards: [f"{DIAGNOSIS}/diagnosis.json"] if wildcards.model == "fmu_effects" else [],
            grid=GRID_CHOICE,
        output:
            fmu=f"{EXPORT_DIR}/{fmu_file_pattern(CASE)}",
            record=f"{EXPORT_DIR}/{{model}}.json",
        params:
            case=CASE,
            case_sections=case_sections(),
            check_maneuvers=EXPORT_CHECK_MANEUVERS,
        wildcard_constraints:
            model="|".join(EXPORT_MODELS),
        threads: 1
        log:
            f"{RESULTS}/logs/export/{{model}}.log",
        benchmark:
            f"{RESULTS}/benchmarks/export/{{model}}.tsv"
        script:
            "../scripts/export.py"

    ALL_TARGETS.extend(exported_fmu(model) for model in EXPORT_MODELS)
