# Hyperparameter searches over neural FMUs (Hyperband, paper Sec. 3.2): the training data are prepared
# once (rule hpo_prepare), then each search is planned and its MLflow parent run created (rule hpo_plan),
# every (configuration, rung) is one job (rule train_rung) that resumes the previous rung's checkpoint, the
# survivors of each (bracket, rung) are chosen by a checkpoint rule (select_rung), and the best
# configuration over all brackets is written to {search}/best.json (rule select_best).
# Search "hpo" trains the paper's neural FMU (the FMU under the ANN). When model.physics_terms names a
# physical layer, search "hybrid" trains the hybrid (the FMU plus the diagnosed effects under the ANN) with
# the same search space, after the diagnosis (its diagnosis/diagnosed_model.pkl); config.hpo.searches gives a
# search its own budget. With config.hpo.selection.maneuvers, rule score_finalist runs each of a search's finalists
# open loop over whole maneuvers (one job per finalist), score_finalists chooses and select_best takes that one.
from hybridfmu.data.settings import section_settings
from hybridfmu.io import read_json
from hybridfmu.tracking import experiment_name
from hybridfmu.training.maneuver_roles import role_maneuver
from hybridfmu.training.plan import search_settings
from hybridfmu.training.candidates import candidate_names
from hybridfmu.training.hyperband import hyperband_brackets

HPO = section_settings(config.get("hpo"), "hpo")
TRAINING = section_settings(config.get("training"), "training")
MODEL = section_settings(config.get("model"), "model")
PREPARED_DIR = f"{RESULTS}/hpo/prepared"
# search -> its model section: the neural FMU without a physical layer, the hybrid with the configured one
# (the neural FMU has no effect coefficients: their step is no parameter of its search)
SEARCH_MODELS = {"hpo": {**{k: v for k, v in MODEL.items() if k != "physics_coefficient_step"}, "physics_terms": "none"}}
if HYBRID:
    SEARCH_MODELS["hybrid"] = MODEL
SEARCHES = list(SEARCH_MODELS)
# search -> its settings (config.hpo with its own config.hpo.searches.<search>) and its brackets by index
SEARCH_HPO = {search: search_settings(HPO, search) for search in SEARCHES}
SEARCH_BRACKETS = {search: {bracket.s: bracket for bracket in hyperband_brackets(settings["R"], settings["eta"])}
                   for search, settings in SEARCH_HPO.items()}
# searches whose best configuration is chosen over whole maneuvers (rule score_finalists)
FINALIST_SEARCHES = [search for search, settings in SEARCH_HPO.items() if "selection" in settings]
TRAIN_MANEUVERS = {"train": role_maneuver(config, "train", TRAINING["train_maneuver"]),
                   "validation": role_maneuver(config, "validation", TRAINING["validation_maneuver"])}


def search_diagnosed_model(wildcards):
    """The diagnosed model a search's jobs read: the hybrid's physical layer (none for the neural FMU)."""
    return [DIAGNOSED_MODEL] if wildcards.search == "hybrid" else []


def search_time_offset(wildcards):
    """Where a search's delays start when model.input_delay.init_s is time_offset: the time-offset stage's
    estimates with the FMU (the neural FMU), or with the hybrid's physical layer (rule hybrid_time_offset)."""
    if MODEL["input_delay"]["init_s"] != "time_offset":
        return []
    if wildcards.search == "hybrid":
        return HYBRID_TIME_OFFSET
    return [f"{RESULTS}/evaluation/time_offset.json"]


def previous_rung_checkpoint(wildcards):
    """The checkpoint a rung resumes (none for rung 0)."""
    rung = int(wildcards.rung)
    if rung == 0:
        return []
    return f"{RESULTS}/{wildcards.search}/b{wildcards.bracket}/r{rung - 1}/c{wildcards.config}/checkpoint.pt"


def rung_configs(search, bracket, rung):
    """Configurations trained in a rung: all of the bracket in rung 0, else the previous rung's survivors."""
    if rung == 0:
        return list(range(SEARCH_BRACKETS[search][bracket].n_configs))
    selection = checkpoints.select_rung.get(search=search, bracket=bracket, rung=rung - 1).output.selection
    return read_json(selection)["survivors"]


def rung_results(wildcards):
    bracket, rung = int(wildcards.bracket), int(wildcards.rung)
    return [f"{RESULTS}/{wildcards.search}/b{bracket}/r{rung}/c{config_index}/result.json"
            for config_index in rung_configs(wildcards.search, bracket, rung)]


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
        train=f"{PREPARED_DIR}/train.npz",
        validation=f"{PREPARED_DIR}/validation.npz",
        statistics=f"{PREPARED_DIR}/statistics.json",
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
        train=f"{PREPARED_DIR}/train.npz",
        validation=f"{PREPARED_DIR}/validation.npz",
        statistics=f"{PREPARED_DIR}/statistics.json",
        # the delays start at the time-offset stage's estimates when model.input_delay.init_s is time_offset
        time_offset=search_time_offset,
    output:
        plan=f"{RESULTS}/{{search}}/plan.json",
    params:
        case=CASE,
        seed=config.get("seed", 0),
        # the final choice (selection) is no part of the plan: changing it reruns score_finalists and select_best only
        hpo=lambda wildcards: {k: v for k, v in SEARCH_HPO[wildcards.search].items() if k != "selection"},
        training=TRAINING,
        model=lambda wildcards: SEARCH_MODELS[wildcards.search],
        case_sections=case_sections(),
        # where the search's runs go, as configured (resolved by the job: a moved project plans nothing anew)
        mlflow=mlflow_destination(),
        results_dir=config.get("results_dir", "results"),
        experiment=experiment_name(config.get("mlflow"), CASE),
    wildcard_constraints:
        search="|".join(SEARCHES),
    priority: search_priority
    log:
        f"{RESULTS}/logs/hpo_plan/{{search}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/hpo_plan/{{search}}.tsv"
    script:
        "../scripts/train_plan.py"


if HYBRID_TIME_OFFSET:

    rule hybrid_time_offset:
        """The time-offset stage's group estimates on the hybrid's physical layer: its delays' start."""
        input:
            fmu=fmu_path(),
            calibration=CALIBRATION_JSON,
            diagnosed=DIAGNOSED_MODEL,
            data=f"{RESULTS}/data/{time_offset_maneuver()}.parquet",
        output:
            summary=HYBRID_TIME_OFFSET[0],
        params:
            maneuver=time_offset_maneuver(),
            options=config.get("evaluation", {}).get("time_offset", {}),
            model=SEARCH_MODELS["hybrid"],
            case=case_sections(),
        priority: HYBRID_CHAIN_PRIORITY
        log:
            f"{RESULTS}/logs/hybrid_time_offset/hybrid_time_offset.log",
        benchmark:
            f"{RESULTS}/benchmarks/hybrid_time_offset/hybrid_time_offset.tsv"
        script:
            "../scripts/hybrid_time_offset.py"


def shared_rollout(wildcards):
    """The hybrid search's shared rollout of its untrained state, for its rung-0 trials (rule
    physical_layer_rollout); none for the neural FMU and later rungs."""
    return [PHYSICAL_LAYER_ROLLOUT] if wildcards.search == "hybrid" and int(wildcards.rung) == 0 else []


if HYBRID:

    rule physical_layer_rollout:
        """The untrained hybrid (its physical layer) over the validation segments, once for all rung-0 trials."""
        input:
            plan=f"{RESULTS}/hybrid/plan.json",
            train=f"{PREPARED_DIR}/train.npz",
            validation=f"{PREPARED_DIR}/validation.npz",
            statistics=f"{PREPARED_DIR}/statistics.json",
            fmu=fmu_path(),
            calibration=CALIBRATION_JSON,
            diagnosed=DIAGNOSED_MODEL,
        output:
            rollout=PHYSICAL_LAYER_ROLLOUT,
        params:
            model=SEARCH_MODELS["hybrid"],
        threads: 1
        priority: HYBRID_CHAIN_PRIORITY
        log:
            f"{RESULTS}/logs/physical_layer_rollout/physical_layer_rollout.log",
        benchmark:
            f"{RESULTS}/benchmarks/physical_layer_rollout/physical_layer_rollout.tsv"
        script:
            "../scripts/train_physical_layer_rollout.py"


    rule physical_layer_checkpoint:
        """The hybrid's physical layer (the untrained hybrid: ANN at zero) as a candidate of the final choice."""
        input:
            plan=f"{RESULTS}/hybrid/plan.json",
            train=f"{PREPARED_DIR}/train.npz",
            validation=f"{PREPARED_DIR}/validation.npz",
            statistics=f"{PREPARED_DIR}/statistics.json",
            fmu=fmu_path(),
            calibration=CALIBRATION_JSON,
            diagnosed=DIAGNOSED_MODEL,
        output:
            checkpoint=PHYSICAL_LAYER_CHECKPOINT,
        params:
            model=SEARCH_MODELS["hybrid"],
        threads: 1
        log:
            f"{RESULTS}/logs/physical_layer_checkpoint/physical_layer_checkpoint.log",
        script:
            "../scripts/train_physical_layer_checkpoint.py"


rule train_rung:
    input:
        plan=f"{RESULTS}/{{search}}/plan.json",
        train=f"{PREPARED_DIR}/train.npz",
        validation=f"{PREPARED_DIR}/validation.npz",
        statistics=f"{PREPARED_DIR}/statistics.json",
        fmu=fmu_path(),
        calibration=CALIBRATION_JSON,
        previous=previous_rung_checkpoint,
        diagnosed=search_diagnosed_model,
        shared_rollout=shared_rollout,
    output:
        checkpoint=f"{RESULTS}/{{search}}/b{{bracket}}/r{{rung}}/c{{config}}/checkpoint.pt",
        result=f"{RESULTS}/{{search}}/b{{bracket}}/r{{rung}}/c{{config}}/result.json",
    params:
        # the search settings (config.hpo) reach a rung through the plan
        model=lambda wildcards: SEARCH_MODELS[wildcards.search],
        training=TRAINING,
        case=case_sections(),
    wildcard_constraints:
        search="|".join(SEARCHES),
        bracket=r"\d+",
        rung=r"\d+",
        config=r"\d+",
    threads: 1
    priority: search_priority
    log:
        f"{RESULTS}/logs/train_rung/{{search}}/b{{bracket}}_r{{rung}}_c{{config}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/train_rung/{{search}}/b{{bracket}}_r{{rung}}_c{{config}}.tsv"
    script:
        "../scripts/train_rung.py"


checkpoint select_rung:
    input:
        plan=f"{RESULTS}/{{search}}/plan.json",
        results=rung_results,
    output:
        selection=f"{RESULTS}/{{search}}/b{{bracket}}/r{{rung}}/selection.json",
    wildcard_constraints:
        search="|".join(SEARCHES),
        bracket=r"\d+",
        rung=r"\d+",
    priority: search_priority
    log:
        f"{RESULTS}/logs/select_rung/{{search}}/b{{bracket}}_r{{rung}}.log",
    script:
        "../scripts/train_select_rung.py"


def search_selections(wildcards):
    """Every rung's selection of every bracket of a search."""
    return [f"{RESULTS}/{wildcards.search}/b{bracket.s}/r{rung.index}/selection.json"
            for bracket in SEARCH_BRACKETS[wildcards.search].values() for rung in bracket.rungs]


def selection_maneuvers(search):
    """Role -> maneuver name of the maneuvers a search's finalists are scored on (config hpo.selection)."""
    return {role: TRAIN_MANEUVERS[role] for role in SEARCH_HPO[search]["selection"]["maneuvers"]}


def finalist_candidates(search):
    """The candidates of a search's final choice, one score_finalist job each: rank1 .. rank<top> and, for the
    hybrid, its physical layer."""
    return candidate_names(SEARCH_HPO[search]["selection"]["top"], search == "hybrid")


rule score_finalist:
    """One candidate of the search's final choice open loop over whole maneuvers against the FMU (config
    hpo.selection): the finalist with the k-th best objective (rank<k>) or the hybrid's physical layer."""
    input:
        plan=f"{RESULTS}/{{search}}/plan.json",
        selections=search_selections,
        fmu=fmu_path(),
        calibration=CALIBRATION_JSON,
        data=lambda wildcards: [f"{RESULTS}/data/{name}.parquet"
                                for name in selection_maneuvers(wildcards.search).values()],
        baselines=lambda wildcards: [f"{RESULTS}/baseline/{name}.parquet"
                                     for name in selection_maneuvers(wildcards.search).values()],
        diagnosed=search_diagnosed_model,
        # a hybrid's physical layer competes with its finalists: the chosen hybrid is never worse than it there
        physical_layer=lambda wildcards: [PHYSICAL_LAYER_CHECKPOINT] if wildcards.search == "hybrid" else [],
    output:
        score=f"{RESULTS}/{{search}}/finalists/{{candidate}}.json",
    params:
        maneuvers=lambda wildcards: list(selection_maneuvers(wildcards.search).values()),
        top=lambda wildcards: SEARCH_HPO[wildcards.search]["selection"]["top"],
        case=case_sections(),
    wildcard_constraints:
        search="|".join(FINALIST_SEARCHES) if FINALIST_SEARCHES else "(?!)",
        candidate=r"rank\d+|physical_layer",
    threads: 1
    log:
        f"{RESULTS}/logs/score_finalist/{{search}}/{{candidate}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/score_finalist/{{search}}/{{candidate}}.tsv"
    script:
        "../scripts/train_score_finalist.py"


rule score_finalists:
    """The search's final choice among its scored candidates (the smallest score)."""
    input:
        plan=f"{RESULTS}/{{search}}/plan.json",
        candidates=lambda wildcards: [f"{RESULTS}/{wildcards.search}/finalists/{candidate}.json"
                                      for candidate in finalist_candidates(wildcards.search)],
    output:
        finalists=f"{RESULTS}/{{search}}/finalists.json",
    params:
        maneuvers=lambda wildcards: list(selection_maneuvers(wildcards.search).values()),
        top=lambda wildcards: SEARCH_HPO[wildcards.search]["selection"]["top"],
        case=case_sections(),
    wildcard_constraints:
        search="|".join(FINALIST_SEARCHES) if FINALIST_SEARCHES else "(?!)",
    log:
        f"{RESULTS}/logs/score_finalists/{{search}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/score_finalists/{{search}}.tsv"
    script:
        "../scripts/train_score_finalists.py"


rule select_best:
    input:
        plan=f"{RESULTS}/{{search}}/plan.json",
        selections=search_selections,
        finalists=lambda wildcards: ([f"{RESULTS}/{wildcards.search}/finalists.json"]
                                     if wildcards.search in FINALIST_SEARCHES else []),
    output:
        best=f"{RESULTS}/{{search}}/best.json",
        model=f"{RESULTS}/{{search}}/best_model.pt",
        summary=f"{RESULTS}/{{search}}/summary.json",
    params:
        case=CASE,
    wildcard_constraints:
        search="|".join(SEARCHES),
    log:
        f"{RESULTS}/logs/select_best/{{search}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/select_best/{{search}}.tsv"
    script:
        "../scripts/train_select_best.py"


ALL_TARGETS.extend([f"{RESULTS}/{search}/{name}.json" for search in SEARCHES for name in ("best", "summary")])
