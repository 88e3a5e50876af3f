# The FMU open loop over each whole maneuver (rule simulate_baseline), and the short window that
# shows the time offset between data and model (rule time_offset, paper Fig. 6). Every stage that
# simulates the FMU loads it with the calibrated parameters (rule calibrate) and reads the data through
# the case's roles; the definitions below are shared with train.smk and evaluate.smk.
from hybridfmu.data.roles import case_roles
from hybridfmu.data.settings import section_settings

CALIBRATION_JSON = f"{RESULTS}/calibration/calibration.json"
_ROLES = case_roles(config)
TARGET_SIGNALS = _ROLES.target_signals
UNMEASURED_STATES = _ROLES.unmeasured_states


def case_sections():
    """The config a stage reads its data through (params of every such stage, so that a change reruns it):
    the case's roles (``hybridfmu.data.roles.case_roles`` builds them from the FMU's interface and the sections
    signals, transforms, roles) and config.maneuvers (roles, initial states). The FMU's parameters are not
    part of it: they reach these stages through the calibration."""
    return {"fmu": fmu_interface(), "maneuvers": config["maneuvers"], "signals": config.get("signals", {}),
            "transforms": config.get("transforms", []), "roles": config.get("roles", {})}



def time_offset_maneuver():
    """Maneuver of the time-offset figure: the configured one, else the first train maneuver."""
    chosen = config.get("evaluation", {}).get("time_offset", {}).get("maneuver", "")
    if chosen:
        if chosen not in config["maneuvers"]:
            raise ValueError(f"config.evaluation.time_offset.maneuver: {chosen!r} is not a maneuver of the case; "
                             f"expected one of {MANEUVERS}")
        return chosen
    train = [name for name, item in config["maneuvers"].items() if item["role"] == "train"]
    return train[0] if train else MANEUVERS[0]


rule simulate_baseline:
    input:
        fmu=fmu_path(),
        calibration=CALIBRATION_JSON,
        data=f"{RESULTS}/data/{{maneuver}}.parquet",
    output:
        trajectory=f"{RESULTS}/baseline/{{maneuver}}.parquet",
        metrics=f"{RESULTS}/baseline/{{maneuver}}.metrics.json",
    params:
        case=case_sections(),
    wildcard_constraints:
        maneuver="|".join(MANEUVERS),
    log:
        f"{RESULTS}/logs/simulate_baseline/{{maneuver}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/simulate_baseline/{{maneuver}}.tsv"
    script:
        "../scripts/simulate_baseline.py"


rule time_offset:
    input:
        fmu=fmu_path(),
        calibration=CALIBRATION_JSON,
        data=f"{RESULTS}/data/{time_offset_maneuver()}.parquet",
    output:
        window=f"{RESULTS}/evaluation/time_offset.parquet",
        summary=f"{RESULTS}/evaluation/time_offset.json",
    params:
        maneuver=time_offset_maneuver(),
        options=config.get("evaluation", {}).get("time_offset", {}),
        # the delay's groups and range (what the per-group estimate searches), not how it is trained
        delay={key: section_settings(config.get("model"), "model")["input_delay"][key]
               for key in ("groups", "min_s", "max_s")},
        case=case_sections(),
    log:
        f"{RESULTS}/logs/time_offset/time_offset.log",
    benchmark:
        f"{RESULTS}/benchmarks/time_offset/time_offset.tsv"
    script:
        "../scripts/time_offset.py"


ALL_TARGETS.extend(expand(f"{RESULTS}/baseline/{{maneuver}}.{{ext}}", maneuver=MANEUVERS,
                          ext=["parquet", "metrics.json"]))
