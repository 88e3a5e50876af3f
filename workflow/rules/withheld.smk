# Withheld-effect check (target `withheld`): per seed of config.withheld.seeds, cases whose bench has an
# effect the FMU lacks (every effect of the bench's catalog at withheld.sizes_per_effect sizes, configured
# pairs, and none) plus motor parameter offsets are generated, emulated, ingested, segmented and diagnosed;
# the summary scores the diagnoses against the ground truth (hybridfmu_bench.withheld.report).
# Cases (ids s<seed>__...) are wildcards, so `snakemake -j2 withheld` runs them in parallel.
from hybridfmu_bench.withheld.suite import case_names as _withheld_case_names
from hybridfmu_bench.withheld.suite import case_selection as _withheld_case_selection

WITHHELD = f"{config.get('results_dir', 'results')}/withheld"
WITHHELD_CASES = _withheld_case_names(config) if config.get("withheld", {}).get("maneuvers") else []
WITHHELD_MANEUVERS = list(config.get("withheld", {}).get("maneuvers", {}))
WITHHELD_DURATION_S = config.get("withheld", {}).get("duration_s", 6.0)
# read by the summary only (a change of them rescores, it does not regenerate or rediagnose any case)
WITHHELD_SUMMARY_KEYS = ("expected", "targets", "background", "calibration_seeds")


def withheld_case_sections(case):
    """The main case's config the withheld case ``case`` is generated from: no MLflow run, calibration, training,
    search or evaluation happens for it, its maneuvers are those of config.withheld, and of the keys that choose
    which cases exist it gets only those that make it exist (adding a seed or a pair reruns no other case)."""
    sections = config_sections("case", "results_dir", "seed", "fmu", "bench", "signals", "transforms", "roles",
                               "ingest", "segments", "model", "diagnosis")
    sections["withheld"] = {key: value for key, value in config.get("withheld", {}).items()
                            if key not in WITHHELD_SUMMARY_KEYS}
    sections["withheld"].update(_withheld_case_selection(case))
    return sections


wildcard_constraints:
    wcase="|".join(WITHHELD_CASES) if WITHHELD_CASES else "no-withheld-case",
    wmaneuver="|".join(WITHHELD_MANEUVERS) if WITHHELD_MANEUVERS else "no-withheld-maneuver",


rule withheld_case:
    input:
        fmu=fmu_path(),
    output:
        case=f"{WITHHELD}/cases/{{wcase}}.yaml",
        draw=f"{WITHHELD}/cases/{{wcase}}.draw.json",
    params:
        # the sections a generated case is derived from (hybridfmu_bench.withheld.suite.case_config) and that
        # its emulation, ingestion, segments and diagnosis read; withheld.expected/targets/background only reach the summary
        config=lambda wildcards: withheld_case_sections(wildcards.wcase),
        duration_s=WITHHELD_DURATION_S,
    log:
        f"{WITHHELD}/logs/withheld_case/{{wcase}}.log",
    script:
        "../scripts/withheld_case.py"


rule withheld_emulate:
    input:
        case=f"{WITHHELD}/cases/{{wcase}}.yaml",
    output:
        mdf=f"{WITHHELD}/{{wcase}}/raw/{{wmaneuver}}.mf4",
        truth=f"{WITHHELD}/{{wcase}}/raw/{{wmaneuver}}.truth.json",
    params:
        duration_s=WITHHELD_DURATION_S,
    log:
        f"{WITHHELD}/logs/withheld_emulate/{{wcase}}_{{wmaneuver}}.log",
    benchmark:
        f"{WITHHELD}/benchmarks/withheld_emulate/{{wcase}}_{{wmaneuver}}.tsv"
    script:
        "../scripts/withheld_emulate.py"


rule withheld_ingest:
    input:
        case=f"{WITHHELD}/cases/{{wcase}}.yaml",
        raw=f"{WITHHELD}/{{wcase}}/raw/{{wmaneuver}}.mf4",
    output:
        data=f"{WITHHELD}/{{wcase}}/data/{{wmaneuver}}.parquet",
    log:
        f"{WITHHELD}/logs/withheld_ingest/{{wcase}}_{{wmaneuver}}.log",
    benchmark:
        f"{WITHHELD}/benchmarks/withheld_ingest/{{wcase}}_{{wmaneuver}}.tsv"
    script:
        "../scripts/withheld_ingest.py"


rule withheld_segments:
    input:
        case=f"{WITHHELD}/cases/{{wcase}}.yaml",
        data=f"{WITHHELD}/{{wcase}}/data/{{wmaneuver}}.parquet",
    output:
        segments=f"{WITHHELD}/{{wcase}}/segments/{{wmaneuver}}.json",
        plot=f"{WITHHELD}/{{wcase}}/segments/{{wmaneuver}}.png",
    log:
        f"{WITHHELD}/logs/withheld_segments/{{wcase}}_{{wmaneuver}}.log",
    script:
        "../scripts/withheld_segments.py"


rule withheld_diagnose:
    input:
        case=f"{WITHHELD}/cases/{{wcase}}.yaml",
        fmu=fmu_path(),
        data=expand(f"{WITHHELD}/{{{{wcase}}}}/data/{{m}}.parquet", m=WITHHELD_MANEUVERS),
        segments=expand(f"{WITHHELD}/{{{{wcase}}}}/segments/{{m}}.json", m=WITHHELD_MANEUVERS),
    output:
        json=f"{WITHHELD}/{{wcase}}/diagnosis/diagnosis.json",
        report=f"{WITHHELD}/{{wcase}}/diagnosis/report.md",
    params:
        maneuvers=WITHHELD_MANEUVERS,
    log:
        f"{WITHHELD}/logs/withheld_diagnose/{{wcase}}.log",
    benchmark:
        f"{WITHHELD}/benchmarks/withheld_diagnose/{{wcase}}.tsv"
    script:
        "../scripts/withheld_diagnose.py"


rule withheld_summary:
    input:
        diagnoses=expand(f"{WITHHELD}/{{c}}/diagnosis/diagnosis.json", c=WITHHELD_CASES),
        truths=expand(f"{WITHHELD}/{{c}}/raw/{{m}}.truth.json", c=WITHHELD_CASES,
                      m=WITHHELD_MANEUVERS[-1:]),
        draws=expand(f"{WITHHELD}/cases/{{c}}.draw.json", c=WITHHELD_CASES),
    output:
        csv=f"{WITHHELD}/summary.csv",
        confusion=f"{WITHHELD}/confusion.png",
        detection=f"{WITHHELD}/detection.png",
        markdown=f"{WITHHELD}/summary.md",
        headline=f"{WITHHELD}/headline.md",
    params:
        cases=WITHHELD_CASES,
        expected=config.get("withheld", {}).get("expected", {}),
        targets=config.get("withheld", {}).get("targets", {}),
        background=config.get("withheld", {}).get("background", {}),
        calibration_seeds=config.get("withheld", {}).get("calibration_seeds"),
    log:
        f"{WITHHELD}/logs/withheld_summary/withheld_summary.log",
    script:
        "../scripts/withheld_summary.py"


rule withheld:
    input:
        f"{WITHHELD}/summary.csv",
        f"{WITHHELD}/confusion.png",
        f"{WITHHELD}/detection.png",
        f"{WITHHELD}/summary.md",
        f"{WITHHELD}/headline.md",
