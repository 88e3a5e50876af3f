# Target `robustness`: the whole case rerun with each master seed of config.robustness.seeds (a nested Snakemake
# run per seed, outputs under <results_dir>/robustness/seed<seed>/), the case's own seed being its own run; the
# summary pools the test figures of every (seed, maneuver) (hybridfmu.evaluation.robustness).

ROBUSTNESS_SEEDS = [int(seed) for seed in (config.get("robustness") or {}).get("seeds", [])]
ROBUSTNESS = f"{RESULTS}/robustness"
OWN_SEED = int(config.get("seed", 0))
OTHER_SEEDS = [seed for seed in ROBUSTNESS_SEEDS if seed != OWN_SEED]


def robustness_cores():
    """Cores of a seed's nested run: all of this run's (--cores / -j), 1 where none is set (a cluster profile)."""
    from snakemake.exceptions import WorkflowError

    try:
        return max(1, int(workflow.cores))
    except (WorkflowError, TypeError):
        return 1


if "test" in EVAL_ROLES:

    rule robustness_seed:
        output:
            metrics=f"{ROBUSTNESS}/seed{{seed}}/test.json",
        params:
            config=dict(config),
            config_path=lambda wildcards: f"{ROBUSTNESS}/seed{wildcards.seed}/config.yaml",
            snakefile=workflow.main_snakefile,
            run_log=lambda wildcards: f"{ROBUSTNESS}/seed{wildcards.seed}/run.log",
        wildcard_constraints:
            seed="|".join(map(str, OTHER_SEEDS)) if OTHER_SEEDS else "(?!)",
        threads: robustness_cores()
        log:
            f"{RESULTS}/logs/robustness_seed/seed{{seed}}.log",
        benchmark:
            f"{RESULTS}/benchmarks/robustness_seed/seed{{seed}}.tsv"
        script:
            "../scripts/robustness_seed.py"

    rule robustness_summary:
        input:
            own=f"{RESULTS}/metrics/test.json",
            others=expand(f"{ROBUSTNESS}/seed{{seed}}/test.json", seed=OTHER_SEEDS),
            benchmarks=expand(f"{RESULTS}/benchmarks/robustness_seed/seed{{seed}}.tsv", seed=OTHER_SEEDS),
        output:
            summary=f"{ROBUSTNESS}/summary.json",
            markdown=f"{ROBUSTNESS}/summary.md",
        params:
            case=CASE,
            own_seed=OWN_SEED,
            other_seeds=OTHER_SEEDS,
            run_logs=[f"{ROBUSTNESS}/seed{seed}/run.log" for seed in OTHER_SEEDS],  # jobs each seed's run ran
            reference=EVAL_CONFIG.get("reference", {}),  # the neural FMU's medians beside e.g. the paper's factors
        log:
            f"{RESULTS}/logs/robustness_summary/robustness_summary.log",
        script:
            "../scripts/robustness_summary.py"

    rule robustness:
        input:
            f"{ROBUSTNESS}/summary.json",
