# Calibration (rule calibrate): FMU parameters and unmeasured initial states fitted on the train maneuvers
# (hybridfmu.calibration); later stages load the FMU with its parameters.
from hybridfmu.calibration.data import maneuvers_with_role as _calibration_maneuvers

CALIBRATION_MANEUVERS = _calibration_maneuvers(config, "train") + _calibration_maneuvers(config, "validation")


rule calibrate:
    input:
        fmu=fmu_path(),
        data=expand(f"{RESULTS}/data/{{maneuver}}.parquet", maneuver=CALIBRATION_MANEUVERS),
    output:
        calibration=f"{RESULTS}/calibration/calibration.json",
        figure=f"{RESULTS}/calibration/calibration.png",
    params:
        maneuver_names=CALIBRATION_MANEUVERS,
        # what hybridfmu.calibration reads: its settings, the FMU (interface, parameters), the roles, the
        # maneuvers (roles, initial states) and, for its MLflow run, the case, mlflow and results_dir
        config=config_sections("case", "results_dir", "mlflow", "calibration", "fmu", "maneuvers", "signals",
                               "transforms", "roles"),
    log:
        f"{RESULTS}/logs/calibrate/calibrate.log",
    benchmark:
        f"{RESULTS}/benchmarks/calibrate/calibrate.tsv"
    script:
        "../scripts/calibrate.py"


ALL_TARGETS.extend([f"{RESULTS}/calibration/calibration.json", f"{RESULTS}/calibration/calibration.png"])
