# Raw logs -> the case's signals in their model units on the case's grid (rule ingest), and the spans
# of each maneuver that carry information (rule select_segments, paper Fig. 8).


def raw_log(wildcards):
    """The raw log of a maneuver, as the case config names it."""
    return config["maneuvers"][wildcards.maneuver]["raw"]


def data_job_config(wildcards, *sections, maneuver_entry=True):
    """The config a data job reads (a job reruns when it changes, and only then): the named sections, what
    locates the FMU's interface (declared units) and, with ``maneuver_entry``, only this maneuver's entry
    of config.maneuvers (channel overrides, slice)."""
    job_config = {**config_sections(*sections), "fmu": fmu_interface()}
    if maneuver_entry:
        job_config["maneuvers"] = {wildcards.maneuver: config["maneuvers"][wildcards.maneuver]}
    return job_config


# Without config.ingest.rate_hz, or with an FMU input whose convention between samples the config leaves out
# (config.roles.between_samples), the grid's rate and those conventions are chosen once from the logs of the train
# and validation maneuvers (rule choose_grid; the test maneuvers inform no choice) and read by each ingest job;
# with everything set, no job reads the logs for that.
from hybridfmu.data.between_samples import declared_conventions as _declared_conventions

GRID_CHOICE = ([] if _section_settings(config.get("ingest"), "ingest")["rate_hz"] is not None
               and None not in _declared_conventions(config, ROLES).values()
               else [f"{RESULTS}/data/grid.json"])
GRID_MANEUVERS = [name for name in MANEUVERS if config["maneuvers"][name]["role"] != "test"]


rule choose_grid:
    input:
        raw=[config["maneuvers"][name]["raw"] for name in GRID_MANEUVERS],
    output:
        grid=f"{RESULTS}/data/grid.json",
    params:
        config=lambda wildcards: {**config_sections("ingest", "signals", "transforms", "roles"), "fmu": fmu_interface(),
                                  "maneuvers": {name: config["maneuvers"][name] for name in GRID_MANEUVERS}},
    log:
        f"{RESULTS}/logs/choose_grid.log",
    script:
        "../scripts/choose_grid.py"


rule ingest:
    input:
        raw=raw_log,
        grid=GRID_CHOICE,
    output:
        data=f"{RESULTS}/data/{{maneuver}}.parquet",
    params:
        config=lambda wildcards: data_job_config(wildcards, "ingest", "signals", "transforms", "roles"),
    wildcard_constraints:
        maneuver="|".join(MANEUVERS),
    log:
        f"{RESULTS}/logs/ingest/{{maneuver}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/ingest/{{maneuver}}.tsv"
    script:
        "../scripts/ingest.py"


rule select_segments:
    input:
        data=f"{RESULTS}/data/{{maneuver}}.parquet",
    output:
        segments=f"{RESULTS}/segments/{{maneuver}}.json",
        plot=f"{RESULTS}/segments/{{maneuver}}.png",
    params:
        # the spans depend on the ingested data and the settings, not on the maneuver's entry
        config=lambda wildcards: data_job_config(wildcards, "segments", "signals", "transforms", "roles",
                                                 maneuver_entry=False),
    wildcard_constraints:
        maneuver="|".join(MANEUVERS),
    log:
        f"{RESULTS}/logs/select_segments/{{maneuver}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/select_segments/{{maneuver}}.tsv"
    script:
        "../scripts/select_segments.py"


ALL_TARGETS.extend(expand(f"{RESULTS}/data/{{maneuver}}.parquet", maneuver=MANEUVERS))
ALL_TARGETS.extend(expand(f"{RESULTS}/segments/{{maneuver}}.{{ext}}", maneuver=MANEUVERS, ext=["json", "png"]))
