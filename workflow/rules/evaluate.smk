# Evaluation of the best neural FMU against the FMU on the validation and test maneuvers, beside the FMU plus
# the diagnosed effects and (model.physics_terms) the best hybrid: the open-loop
# simulation of each whole maneuver (rule simulate_best, one job per maneuver), the errors on whole
# trajectories and zoomed intervals with the MLflow run (rule evaluate), the paper's figures (rule plot)
# and the report (rule report).

EVAL_ROLES = [role for role in ("validation", "test")
              if any(item["role"] == role for item in config["maneuvers"].values())]
EVAL_MANEUVERS = [name for name, item in config["maneuvers"].items() if item["role"] in EVAL_ROLES]
EVAL_CONFIG = config.get("evaluation", {})
FIGURES = f"{RESULTS}/figures"


def evaluation_figure_specs():
    """(name, path, maneuver or None, caption) of every figure: per evaluated maneuver and target signal
    (TARGET_SIGNALS, baseline.smk) the whole trajectory and the zoomed intervals (paper Figs. 9-16); the time
    offset (Fig. 6), training curves, Hyperband overview."""
    specs = [(kind, f"{FIGURES}/{kind}.png", None, kind) for kind in ("time_offset", "training_curves", "hyperband")]
    for maneuver in EVAL_MANEUVERS:
        for signal in TARGET_SIGNALS:
            for suffix, caption in (("", "trajectory"), ("_zoom", "trajectory_zoom")):
                name = f"{maneuver}_{signal}{suffix}"
                specs.append((name, f"{FIGURES}/{name}.png", maneuver, caption))
    return specs


def evaluation_figures():
    """Figure name -> path."""
    return {name: path for name, path, _, _ in evaluation_figure_specs()}


def truth_files():
    """Ground-truth files beside the raw logs (written by the bench emulator of a demo case)."""
    files = []
    for name in EVAL_MANEUVERS:
        raw = config["maneuvers"][name]["raw"]
        truth = str(Path(raw).with_suffix("")) + ".truth.json"
        if "bench" in config or Path(truth).exists():
            files.append(truth)
    return files


rule simulate_best:
    input:
        best=f"{RESULTS}/hpo/best.json",
        fmu=fmu_path(),
        calibration=CALIBRATION_JSON,
        data=f"{RESULTS}/data/{{maneuver}}.parquet",
        baseline=f"{RESULTS}/baseline/{{maneuver}}.parquet",
        # the FMU plus the diagnosed effects, and the hybrid around it when the case trains one
        diagnosed=DIAGNOSED_MODEL,
        hybrid_best=[f"{RESULTS}/hybrid/best.json"] if HYBRID else [],
        # the best any model could reach (the bench's true plant, emulated cases only; bench.smk)
        ceiling=[f"{RESULTS}/evaluation/ceiling/{{maneuver}}.parquet"] if "bench" in config else [],
    output:
        trajectory=f"{RESULTS}/evaluation/trajectories/{{maneuver}}.parquet",
        learned=f"{RESULTS}/evaluation/trajectories/{{maneuver}}.learned.json",
    params:
        case=case_sections(),
        window_length_s=EVAL_CONFIG.get("windows", {}).get("length_s"),
    wildcard_constraints:
        maneuver="|".join(EVAL_MANEUVERS) if EVAL_MANEUVERS else "(?!)",
    threads: 1
    log:
        f"{RESULTS}/logs/simulate_best/{{maneuver}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/simulate_best/{{maneuver}}.tsv"
    script:
        "../scripts/simulate_best.py"


# Closed loop (config closed_loop: the case's control software): each model driven by the controller over all
# evaluated maneuvers side by side, one job per model (hybridfmu.evaluation.closed_loop).
CLOSED_LOOP = bool((config.get("closed_loop") or {}).get("controller"))
CLOSED_LOOP_MODELS = (["fmu", "neural_fmu"] + (["fmu_effects", "hybrid"] if HYBRID else [])) if CLOSED_LOOP else []
CLOSED_LOOP_DIR = f"{RESULTS}/evaluation/closed_loop"

if CLOSED_LOOP:

    rule simulate_closed_loop:
        input:
            best=f"{RESULTS}/hpo/best.json",
            fmu=fmu_path(),
            calibration=CALIBRATION_JSON,
            data=expand(f"{RESULTS}/data/{{maneuver}}.parquet", maneuver=EVAL_MANEUVERS),
            # each model's own files only: the FMU's, the neural FMU's and the physical layer's jobs run while the
            # hybrid's search still trains
            diagnosed=lambda wildcards: [DIAGNOSED_MODEL] if wildcards.model in ("fmu_effects", "hybrid") else [],
            hybrid_best=lambda wildcards: [f"{RESULTS}/hybrid/best.json"] if wildcards.model == "hybrid" else [],
            physical_layer=lambda wildcards: [PHYSICAL_LAYER_CHECKPOINT] if wildcards.model == "fmu_effects" else [],
        output:
            trajectories=expand(f"{CLOSED_LOOP_DIR}/{{{{model}}}}/{{maneuver}}.parquet", maneuver=EVAL_MANEUVERS),
        params:
            case=case_sections(),
            maneuvers=EVAL_MANEUVERS,
            controller_config={**config_sections("bench", "seed", "closed_loop"),
                               "fmu": {"parameters": config["fmu"].get("parameters", {})}},
        wildcard_constraints:
            model="|".join(CLOSED_LOOP_MODELS),
        threads: 1
        log:
            f"{RESULTS}/logs/simulate_closed_loop/{{model}}.log",
        benchmark:
            f"{RESULTS}/benchmarks/simulate_closed_loop/{{model}}.tsv"
        script:
            "../scripts/simulate_closed_loop.py"


rule evaluate:
    input:
        best=f"{RESULTS}/hpo/best.json",
        trajectories=expand(f"{RESULTS}/evaluation/trajectories/{{maneuver}}.parquet", maneuver=EVAL_MANEUVERS),
        learned=expand(f"{RESULTS}/evaluation/trajectories/{{maneuver}}.learned.json", maneuver=EVAL_MANEUVERS),
        closed_loop=expand(f"{CLOSED_LOOP_DIR}/{{model}}/{{maneuver}}.parquet", model=CLOSED_LOOP_MODELS,
                           maneuver=EVAL_MANEUVERS),
    output:
        metrics=expand(f"{RESULTS}/metrics/{{role}}.json", role=EVAL_ROLES),
        run=f"{RESULTS}/evaluation/mlflow_run.json",
    params:
        maneuvers={name: config["maneuvers"][name]["role"] for name in EVAL_MANEUVERS},
        zoom=EVAL_CONFIG.get("zoom", {}),
        tolerance=EVAL_CONFIG.get("tolerance", {}),
        closed_loop_models=CLOSED_LOOP_MODELS,
        mlflow=mlflow_destination(),
        results_dir=config.get("results_dir", "results"),
        case=CASE,
    log:
        f"{RESULTS}/logs/evaluate/evaluate.log",
    benchmark:
        f"{RESULTS}/benchmarks/evaluate/evaluate.tsv"
    script:
        "../scripts/evaluate.py"


def figure_outputs():
    """Named plot outputs, each marked as an item of the Snakemake report with its caption."""
    outputs = {}
    for name, path, maneuver, caption in evaluation_figure_specs():
        subcategory = f"{config['maneuvers'][maneuver]['role']}: {maneuver}" if maneuver else "training and data"
        outputs[name] = report(path, caption=f"../report/{caption}.rst", category="Evaluation",
                               subcategory=subcategory, labels={"figure": name})
    return outputs


rule plot:
    input:
        metrics=expand(f"{RESULTS}/metrics/{{role}}.json", role=EVAL_ROLES),
        trajectories=expand(f"{RESULTS}/evaluation/trajectories/{{maneuver}}.parquet", maneuver=EVAL_MANEUVERS),
        time_offset=f"{RESULTS}/evaluation/time_offset.parquet",
        time_offset_summary=f"{RESULTS}/evaluation/time_offset.json",
        best=f"{RESULTS}/hpo/best.json",
    output:
        **figure_outputs(),
    params:
        plot=EVAL_CONFIG.get("plot", {}),
        maneuvers={name: config["maneuvers"][name]["role"] for name in EVAL_MANEUVERS},
        case=case_sections(),
        hpo_dir=f"{RESULTS}/hpo",
    log:
        f"{RESULTS}/logs/plot/plot.log",
    benchmark:
        f"{RESULTS}/benchmarks/plot/plot.tsv"
    script:
        "../scripts/plot.py"


rule report:
    input:
        metrics=expand(f"{RESULTS}/metrics/{{role}}.json", role=EVAL_ROLES),
        best=f"{RESULTS}/hpo/best.json",
        run=f"{RESULTS}/evaluation/mlflow_run.json",
        time_offset_summary=f"{RESULTS}/evaluation/time_offset.json",
        hybrid_time_offset=HYBRID_TIME_OFFSET,
        figures=list(evaluation_figures().values()),
        truth=truth_files(),
        # what the stages chose from the data where the config leaves it out (the grid, the searches' plans)
        chosen=lambda wildcards: GRID_CHOICE + [f"{RESULTS}/{search}/plan.json" for search in SEARCHES],
    output:
        report(f"{RESULTS}/report.md", caption="../report/report_md.rst", category="Evaluation",
               subcategory="report"),
    params:
        case=CASE,
        figure_names=list(evaluation_figures()),
        case_sections=case_sections(),
        reference=EVAL_CONFIG.get("reference", {}),
    log:
        f"{RESULTS}/logs/report/report.log",
    benchmark:
        f"{RESULTS}/benchmarks/report/report.tsv"
    script:
        "../scripts/report.py"


ALL_TARGETS.extend([f"{RESULTS}/report.md", *evaluation_figures().values(),
                    *expand(f"{RESULTS}/metrics/{{role}}.json", role=EVAL_ROLES)])
