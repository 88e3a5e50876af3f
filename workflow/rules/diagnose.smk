# Diagnosis of the sim-to-real gap (rule diagnose): where the gap lies (equation error per measured state,
# operating regions, time), which candidate effect causes it (sparse selection among effects over the
# case's roles, with parameters and uncertainty) and how far it shrinks on the test maneuver once the
# effects are added to the calibrated FMU ({RESULTS}/calibration/calibration.json: parameters and
# unmeasured initial states).
# A case that trains a neural FMU (a `training` or `hpo` section) has the search's best model
# {RESULTS}/hpo/best.json as an input, so the diagnosis always compares with it and runs once after
# the search; a case without one is diagnosed without the comparison. The model the held-out check ends
# with (FMU + effects) is saved as diagnosed_model.pkl: the evaluation simulates it, and a hybrid
# (model.physics_terms, search "hybrid" in train.smk) trains its ANN on top of it.

DIAGNOSIS = f"{RESULTS}/diagnosis"
DIAGNOSED_MODEL = f"{DIAGNOSIS}/diagnosed_model.pkl"  # read by train.smk and evaluate.smk
# the maneuvers the diagnosis reads: every train and validation maneuver, and the test maneuvers of its held-out
# check (config.diagnosis.open_loop.test_maneuvers; all when empty): the others stay unseen until the evaluation
from hybridfmu.diagnosis.settings import diagnosis_maneuvers
DIAGNOSIS_MANEUVERS = diagnosis_maneuvers(config, CONFIG_FILE)
DIAGNOSIS_HAS_TEST = any(config["maneuvers"][name]["role"] == "test" for name in DIAGNOSIS_MANEUVERS)
DIAGNOSIS_FIGURES = ["equation_error", "regions", "candidates", "effects"] + (
    ["waterfall", "open_loop_test", "error_growth"] if DIAGNOSIS_HAS_TEST else [])


DIAGNOSIS_TRAINS_NEURAL_FMU = "training" in config or "hpo" in config
# decided from the config alone (never from existing files), so the DAG is the same on every invocation
DIAGNOSIS_BEST_JSON = [f"{RESULTS}/hpo/best.json"] if DIAGNOSIS_TRAINS_NEURAL_FMU else []


rule diagnose:
    input:
        fmu=fmu_path(),
        data=expand(f"{RESULTS}/data/{{maneuver}}.parquet", maneuver=DIAGNOSIS_MANEUVERS),
        segments=expand(f"{RESULTS}/segments/{{maneuver}}.json", maneuver=DIAGNOSIS_MANEUVERS),
        calibration=f"{RESULTS}/calibration/calibration.json",
        best=DIAGNOSIS_BEST_JSON,
    output:
        json=f"{DIAGNOSIS}/diagnosis.json",
        report=f"{DIAGNOSIS}/report.md",
        diagnosed=DIAGNOSED_MODEL,
        figures=expand(f"{DIAGNOSIS}/{{figure}}.png", figure=DIAGNOSIS_FIGURES),
    params:
        maneuvers=DIAGNOSIS_MANEUVERS,
        # what hybridfmu.diagnosis reads: its settings, the master seed, the FMU (interface, parameters), the
        # roles, the roles and initial states of the maneuvers it reads, the model's end stop, the calibrated
        # parameters and their bounds (recalibrated with the effects when diagnosis.open_loop.refit is on) and, for
        # its MLflow run, the case, mlflow and results_dir
        config={**config_sections("case", "results_dir", "seed", "mlflow", "fmu", "signals", "transforms", "roles",
                                  "model", "calibration", "diagnosis"),
                "maneuvers": {name: config["maneuvers"][name] for name in DIAGNOSIS_MANEUVERS}},
    log:
        f"{RESULTS}/logs/diagnose/diagnose.log",
    benchmark:
        f"{RESULTS}/benchmarks/diagnose/diagnose.tsv"
    script:
        "../scripts/diagnose.py"


ALL_TARGETS.extend([f"{DIAGNOSIS}/diagnosis.json", f"{DIAGNOSIS}/report.md"])
