# The demo's "real hardware" (only for cases with a `bench` section): the test-bench emulator
# writes one MDF4 log and one ground-truth JSON per maneuver, then checks that the realised max load and max
# speed of every two maneuvers of different roles differ by at least 10 %; and the ceiling of the evaluation.

if "bench" in config:
    from hybridfmu_bench.settings import check_raw_paths as _bench_check_raw_paths

    _bench_check_raw_paths(config, RESULTS)

    rule emulate_bench:
        output:
            mdf=f"{RESULTS}/raw/{{maneuver}}.mf4",
            truth=f"{RESULTS}/raw/{{maneuver}}.truth.json",
        params:
            # what hybridfmu_bench reads: the bench, the master seed and the FMU's nominal parameters
            config={**config_sections("bench", "seed"), "fmu": {"parameters": config["fmu"].get("parameters", {})}},
            roles={name: item["role"] for name, item in config["maneuvers"].items()},
        wildcard_constraints:
            maneuver="|".join(MANEUVERS),
        log:
            f"{RESULTS}/logs/emulate_bench/{{maneuver}}.log",
        benchmark:
            f"{RESULTS}/benchmarks/emulate_bench/{{maneuver}}.tsv"
        script:
            "../scripts/emulate_bench.py"

    rule check_bench_spread:
        input:
            truth=expand(f"{RESULTS}/raw/{{maneuver}}.truth.json", maneuver=MANEUVERS),
        output:
            summary=f"{RESULTS}/raw/bench_summary.json",
        params:
            maneuvers=MANEUVERS,
            roles={name: item["role"] for name, item in config["maneuvers"].items()},
        log:
            f"{RESULTS}/logs/check_bench_spread/check_bench_spread.log",
        script:
            "../scripts/check_bench_spread.py"

    # The ceiling: the bench's true plant open loop over an evaluated maneuver from its measured initial state and
    # logged duties (hybridfmu_bench.ceiling); read by the evaluation only (rule simulate_best), never by
    # training, selection or diagnosis.
    rule simulate_ceiling:
        input:
            raw=lambda wildcards: config["maneuvers"][wildcards.maneuver]["raw"],
            data=f"{RESULTS}/data/{{maneuver}}.parquet",
        output:
            trajectory=f"{RESULTS}/evaluation/ceiling/{{maneuver}}.parquet",
        params:
            config={**config_sections("bench", "seed", "signals", "maneuvers", "closed_loop"),
                    "fmu": {"parameters": config["fmu"].get("parameters", {})}},
            case=case_sections(),
            window_length_s=(config.get("evaluation") or {}).get("windows", {}).get("length_s"),
        wildcard_constraints:
            maneuver="|".join(MANEUVERS),
        priority: CEILING_PRIORITY
        log:
            f"{RESULTS}/logs/simulate_ceiling/{{maneuver}}.log",
        benchmark:
            f"{RESULTS}/benchmarks/simulate_ceiling/{{maneuver}}.tsv"
        script:
            "../scripts/simulate_ceiling.py"

    ALL_TARGETS.extend(expand(f"{RESULTS}/raw/{{maneuver}}.{{ext}}", maneuver=MANEUVERS, ext=["mf4", "truth.json"]))
    ALL_TARGETS.append(f"{RESULTS}/raw/bench_summary.json")
