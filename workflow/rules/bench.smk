# The demo's "real hardware" (only for cases with a `bench` section): the test-bench emulator
# writes one MDF4 log and one ground-truth JSON per maneuver, then checks that the maneuvers'
# realised max load and max speed differ by at least 10 % pairwise.

if "bench" in config:
    from hybridfmu.bench.settings import check_raw_paths as _bench_check_raw_paths

    _bench_check_raw_paths(config, RESULTS)

    rule emulate_bench:
        output:
            mdf=f"{RESULTS}/raw/{{maneuver}}.mf4",
            truth=f"{RESULTS}/raw/{{maneuver}}.truth.json",
        params:
            # what hybridfmu.bench reads: the bench, the master seed and the FMU's nominal parameters
            config={**config_sections("bench", "seed"), "fmu": {"parameters": config["fmu"].get("parameters", {})}},
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
        log:
            f"{RESULTS}/logs/check_bench_spread/check_bench_spread.log",
        script:
            "../scripts/check_bench_spread.py"

    ALL_TARGETS.extend(expand(f"{RESULTS}/raw/{{maneuver}}.{{ext}}", maneuver=MANEUVERS, ext=["mf4", "truth.json"]))
    ALL_TARGETS.append(f"{RESULTS}/raw/bench_summary.json")
