# Diagnosis of the sim-to-real gap (rule diagnose): where the gap lies (equation error per measured state,
# operating regions, time), which candidate effect causes it (sparse selection among effects over the
# case's roles, with parameters and uncertainty) and how far it shrinks on the test maneuver once the
# effects are added to the calibrated FMU ({RESULTS}/calibration/calibration.json: parameters and
# unmeasured initial states).
# The diagnosis never waits for a search: it reads the FMU, its calibration and the logs only. The model the
# held-out check ends with (FMU + effects) is saved as diagnosed_model.pkl: the evaluation simulates it, and a
# hybrid (model.physics_terms, search "hybrid" in train.smk) trains its ANN on top of it. A case that trains a
# neural FMU (a `training` or `hpo` section) compares the search's best model with the diagnosis afterwards
# (rule compare_neural_fmu: what the ANN learned against the diagnosed effects, diagnosis/neural_fmu.md).

DIAGNOSIS = f"{RESULTS}/diagnosis"
DIAGNOSED_MODEL = f"{DIAGNOSIS}/diagnosed_model.pkl"  # read by train.smk and evaluate.smk
# the maneuvers the diagnosis reads: every train and validation maneuver, and the test maneuvers of its held-out
# check (config.diagnosis.open_loop.test_maneuvers; all when empty): the others stay unseen until the evaluation
from hybridfmu.diagnosis.settings import diagnosis_maneuvers
DIAGNOSIS_MANEUVERS = diagnosis_maneuvers(config, CONFIG_FILE)
DIAGNOSIS_HAS_TEST = any(config["maneuvers"][name]["role"] == "test" for name in DIAGNOSIS_MANEUVERS)
DIAGNOSIS_FIGURES = ["equation_error", "regions", "candidates", "effects"] + (
    ["waterfall", "open_loop_test", "error_growth"] if DIAGNOSIS_HAS_TEST else [])


# decided from the config alone (never from existing files), so the DAG is the same on every invocation
DIAGNOSIS_COMPARES_NEURAL_FMU = ("training" in config or "hpo" in config) and \
    (config.get("diagnosis") or {}).get("neural_fmu", True)

# what hybridfmu.diagnosis reads: its settings, the master seed, the FMU (interface, parameters), the roles, the
# roles and initial states of the maneuvers it reads, the model's end stop, the calibrated parameters and their
# bounds (recalibrated with the effects when diagnosis.open_loop.refit is on) and, for its MLflow run, the case,
# mlflow and results_dir
DIAGNOSIS_CONFIG = {**config_sections("case", "results_dir", "seed", "mlflow", "fmu", "signals", "transforms", "roles",
                                      "model", "calibration", "diagnosis"),
                    "maneuvers": {name: config["maneuvers"][name] for name in DIAGNOSIS_MANEUVERS}}


rule diagnose:
    input:
        fmu=fmu_path(),
        data=expand(f"{RESULTS}/data/{{maneuver}}.parquet", maneuver=DIAGNOSIS_MANEUVERS),
        segments=expand(f"{RESULTS}/segments/{{maneuver}}.json", maneuver=DIAGNOSIS_MANEUVERS),
        calibration=f"{RESULTS}/calibration/calibration.json",
    output:
        json=f"{DIAGNOSIS}/diagnosis.json",
        report=f"{DIAGNOSIS}/report.md",
        diagnosed=DIAGNOSED_MODEL,
        figures=expand(f"{DIAGNOSIS}/{{figure}}.png", figure=DIAGNOSIS_FIGURES),
    params:
        maneuvers=DIAGNOSIS_MANEUVERS,
        config=DIAGNOSIS_CONFIG,
    # one core: the selections on each fitting maneuver alone then run after the main one (the same results as
    # beside it on two). A job asking for both cores of a 2-core machine starts only when no other job runs, so
    # under `snakemake -j2` it waited for the neural FMU's whole search, the hybrid's chain behind it; on one core
    # it starts as soon as its inputs exist and runs beside that search (`--set-threads diagnose=2` on a larger
    # machine).
    threads: 1
    priority: HYBRID_CHAIN_PRIORITY if HYBRID else 0
    log:
        f"{RESULTS}/logs/diagnose/diagnose.log",
    benchmark:
        f"{RESULTS}/benchmarks/diagnose/diagnose.tsv"
    script:
        "../scripts/diagnose.py"


ALL_TARGETS.extend([f"{DIAGNOSIS}/diagnosis.json", f"{DIAGNOSIS}/report.md"])

if DIAGNOSIS_COMPARES_NEURAL_FMU:

    rule compare_neural_fmu:
        input:
            fmu=fmu_path(),
            data=expand(f"{RESULTS}/data/{{maneuver}}.parquet", maneuver=DIAGNOSIS_MANEUVERS),
            segments=expand(f"{RESULTS}/segments/{{maneuver}}.json", maneuver=DIAGNOSIS_MANEUVERS),
            calibration=f"{RESULTS}/calibration/calibration.json",
            best=f"{RESULTS}/hpo/best.json",
            diagnosed=DIAGNOSED_MODEL,
            diagnosis=f"{DIAGNOSIS}/diagnosis.json",
        output:
            json=f"{DIAGNOSIS}/neural_fmu.json",
            report=f"{DIAGNOSIS}/neural_fmu.md",
        params:
            maneuvers=DIAGNOSIS_MANEUVERS,
            config=DIAGNOSIS_CONFIG,
        log:
            f"{RESULTS}/logs/diagnose/compare_neural_fmu.log",
        benchmark:
            f"{RESULTS}/benchmarks/compare_neural_fmu/compare_neural_fmu.tsv"
        script:
            "../scripts/compare_neural_fmu.py"

    ALL_TARGETS.append(f"{DIAGNOSIS}/neural_fmu.md")
