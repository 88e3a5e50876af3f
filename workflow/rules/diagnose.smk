# Diagnosis of the sim-to-real gap (rule diagnose): where the gap lies (equation error per state,
# operating regions, time), which candidate effect causes it (sparse selection with parameters and
# uncertainty) and how far it shrinks on the test maneuver once the effects are added to the FMU.
# The trained neural FMU is compared with when {RESULTS}/hpo/best.json exists; it is not required.
from pathlib import Path as _DiagnosePath

DIAGNOSIS = f"{RESULTS}/diagnosis"
DIAGNOSIS_HAS_TEST = any(item["role"] == "test" for item in config["maneuvers"].values())
DIAGNOSIS_FIGURES = ["equation_error", "regions", "candidates", "effects"] + (
    ["waterfall", "open_loop_test", "error_growth"] if DIAGNOSIS_HAS_TEST else [])


def diagnosis_best_json(wildcards):
    """The best neural FMU of the search, if one was trained (then the diagnosis compares with it)."""
    best = f"{RESULTS}/hpo/best.json"
    return [best] if _DiagnosePath(best).exists() else []


rule diagnose:
    input:
        fmu=lambda wildcards: fmu_path(),
        data=expand(f"{RESULTS}/data/{{maneuver}}.parquet", maneuver=MANEUVERS),
        segments=expand(f"{RESULTS}/segments/{{maneuver}}.json", maneuver=MANEUVERS),
        best=diagnosis_best_json,
    output:
        json=f"{DIAGNOSIS}/diagnosis.json",
        report=f"{DIAGNOSIS}/report.md",
        figures=expand(f"{DIAGNOSIS}/{{figure}}.png", figure=DIAGNOSIS_FIGURES),
    params:
        maneuvers=MANEUVERS,
    log:
        f"{RESULTS}/logs/diagnose/diagnose.log",
    benchmark:
        f"{RESULTS}/benchmarks/diagnose/diagnose.tsv"
    script:
        "../scripts/diagnose.py"


ALL_TARGETS.extend([f"{DIAGNOSIS}/diagnosis.json", f"{DIAGNOSIS}/report.md"])
