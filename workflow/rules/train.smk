# Hyperparameter search over neural FMUs (Hyperband, paper Sec. 3.2): the training data are prepared
# once (rule hpo_prepare), then the search is planned and its MLflow parent run created (rule hpo_plan),
# every (configuration, rung) is one job (rule train_rung) that resumes the previous rung's checkpoint, the
# survivors of each (bracket, rung) are chosen by a checkpoint rule (select_rung), and the best
# configuration over all brackets is written to hpo/best.json (rule select_best).
from hybridfmu.data.settings import section_settings
from hybridfmu.io import read_json
from hybridfmu.tracking import experiment_name, tracking_uri
from hybridfmu.training.hpo import role_maneuver
from hybridfmu.training.hyperband import hyperband_brackets

HPO = section_settings(config.get("hpo"), "hpo")
TRAINING = section_settings(config.get("training"), "training")
MODEL = section_settings(config.get("model"), "model")
HPO_DIR = f"{RESULTS}/hpo"
HPO_BRACKETS = {bracket.s: bracket for bracket in hyperband_brackets(HPO["R"], HPO["eta"])}
TRAIN_MANEUVERS = {"train": role_maneuver(config, "train", TRAINING["train_maneuver"]),
                   "validation": role_maneuver(config, "validation", TRAINING["validation_maneuver"])}


def previous_rung_checkpoint(wildcards):
    """The checkpoint a rung resumes (none for rung 0)."""
    rung = int(wildcards.rung)
    if rung == 0:
        return []
    return f"{HPO_DIR}/b{wildcards.bracket}/r{rung - 1}/c{wildcards.config}/checkpoint.pt"


def rung_configs(bracket, rung):
    """Configurations trained in a rung: all of the bracket in rung 0, else the previous rung's survivors."""
    if rung == 0:
        return list(range(HPO_BRACKETS[bracket].n_configs))
    selection = checkpoints.select_rung.get(bracket=bracket, rung=rung - 1).output.selection
    return read_json(selection)["survivors"]


def rung_results(wildcards):
    bracket, rung = int(wildcards.bracket), int(wildcards.rung)
    return [f"{HPO_DIR}/b{bracket}/r{rung}/c{config_index}/result.json"
            for config_index in rung_configs(bracket, rung)]


rule hpo_prepare:
    input:
        fmu=fmu_path(),
        calibration=CALIBRATION_JSON,
        train_data=f"{RESULTS}/data/{TRAIN_MANEUVERS['train']}.parquet",
        validation_data=f"{RESULTS}/data/{TRAIN_MANEUVERS['validation']}.parquet",
        train_segments=f"{RESULTS}/segments/{TRAIN_MANEUVERS['train']}.json",
        validation_segments=f"{RESULTS}/segments/{TRAIN_MANEUVERS['validation']}.json",
        # unmeasured states start the training windows from the FMU's baseline (from the calibration)
        baselines=[f"{RESULTS}/baseline/{name}.parquet" for name in TRAIN_MANEUVERS.values()]
        if UNMEASURED_STATES else [],
    output:
        train=f"{HPO_DIR}/prepared/train.npz",
        validation=f"{HPO_DIR}/prepared/validation.npz",
        statistics=f"{HPO_DIR}/prepared/statistics.json",
    params:
        maneuvers=TRAIN_MANEUVERS,
        baselines={role: f"{RESULTS}/baseline/{name}.parquet" for role, name in TRAIN_MANEUVERS.items()},
        case=case_sections(),
    log:
        f"{RESULTS}/logs/hpo_prepare/hpo_prepare.log",
    benchmark:
        f"{RESULTS}/benchmarks/hpo_prepare/hpo_prepare.tsv"
    script:
        "../scripts/train_prepare.py"


rule hpo_plan:
    input:
        # planned only once the data are ingested, segmented and prepared: a bad log or a bad setting of
        # those stages stops the run before the search (and its MLflow parent run) exists
        train=f"{HPO_DIR}/prepared/train.npz",
        validation=f"{HPO_DIR}/prepared/validation.npz",
        statistics=f"{HPO_DIR}/prepared/statistics.json",
        # the delays start at the time-offset stage's estimates when model.input_delay.init_s is time_offset
        time_offset=[f"{RESULTS}/evaluation/time_offset.json"]
        if MODEL["input_delay"]["init_s"] == "time_offset" else [],
    output:
        plan=f"{HPO_DIR}/plan.json",
    params:
        case=CASE,
        seed=config.get("seed", 0),
        hpo=HPO,
        training=TRAINING,
        model=MODEL,
        case_sections=case_sections(),
        tracking_uri=tracking_uri(config.get("mlflow"), config.get("results_dir", "results")),
        experiment=experiment_name(config.get("mlflow"), CASE),
        mlflow=config.get("mlflow", {}),  # the MLflow client's settings (retries, timeouts)
    log:
        f"{RESULTS}/logs/hpo_plan/hpo_plan.log",
    benchmark:
        f"{RESULTS}/benchmarks/hpo_plan/hpo_plan.tsv"
    script:
        "../scripts/train_plan.py"


rule train_rung:
    input:
        plan=f"{HPO_DIR}/plan.json",
        train=f"{HPO_DIR}/prepared/train.npz",
        validation=f"{HPO_DIR}/prepared/validation.npz",
        statistics=f"{HPO_DIR}/prepared/statistics.json",
        fmu=fmu_path(),
        calibration=CALIBRATION_JSON,
        previous=previous_rung_checkpoint,
    output:
        checkpoint=f"{HPO_DIR}/b{{bracket}}/r{{rung}}/c{{config}}/checkpoint.pt",
        result=f"{HPO_DIR}/b{{bracket}}/r{{rung}}/c{{config}}/result.json",
    params:
        # the search settings (config.hpo) reach a rung through the plan
        model=MODEL,
        training=TRAINING,
        case=case_sections(),
        mlflow=config.get("mlflow", {}),  # the MLflow client's settings (retries, timeouts)
    wildcard_constraints:
        bracket=r"\d+",
        rung=r"\d+",
        config=r"\d+",
    threads: 1
    log:
        f"{RESULTS}/logs/train_rung/b{{bracket}}_r{{rung}}_c{{config}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/train_rung/b{{bracket}}_r{{rung}}_c{{config}}.tsv"
    script:
        "../scripts/train_rung.py"


checkpoint select_rung:
    input:
        plan=f"{HPO_DIR}/plan.json",
        results=rung_results,
    output:
        selection=f"{HPO_DIR}/b{{bracket}}/r{{rung}}/selection.json",
    wildcard_constraints:
        bracket=r"\d+",
        rung=r"\d+",
    log:
        f"{RESULTS}/logs/select_rung/b{{bracket}}_r{{rung}}.log",
    script:
        "../scripts/train_select_rung.py"


rule select_best:
    input:
        plan=f"{HPO_DIR}/plan.json",
        selections=[f"{HPO_DIR}/b{bracket.s}/r{rung.index}/selection.json"
                    for bracket in HPO_BRACKETS.values() for rung in bracket.rungs],
    output:
        best=f"{HPO_DIR}/best.json",
        model=f"{HPO_DIR}/best_model.pt",
        summary=f"{HPO_DIR}/summary.json",
    params:
        case=CASE,
        mlflow=config.get("mlflow", {}),  # the MLflow client's settings (retries, timeouts)
    log:
        f"{RESULTS}/logs/select_best/select_best.log",
    benchmark:
        f"{RESULTS}/benchmarks/select_best/select_best.tsv"
    script:
        "../scripts/train_select_best.py"


ALL_TARGETS.extend([f"{HPO_DIR}/best.json", f"{HPO_DIR}/summary.json"])
