"""Speed of the test-bench emulator: simulated seconds per wall second on one core.

Emulates a 25 s maneuver (the demo's train maneuver with its final rest extended to 25 s) with
the demo case's bench section (all its effects on, 10 kHz control, RK4 sub-steps), then writes
its MDF4 log. Prints the timings; the last line is a JSON object with ``realtime_factor``
(simulated s per wall s of the simulation loop), ``realtime_factor_with_output`` (including
references, MDF4 and ground-truth output) and the step rate.

    python benchmarks/bench_emulator.py [--config config/config.yaml] [--duration-s 25] [--substeps N]
"""

from __future__ import annotations

import argparse
import copy
import json
import logging
import tempfile
import time
from pathlib import Path

from hybridfmu_bench.emulate import emulate_bench
from hybridfmu.config import load_case_config

ROOT = Path(__file__).resolve().parents[1]


def extended_config(config_path: Path, duration_s: float, substeps: int | None) -> dict:
    """The case config with a maneuver 'benchmark': the train segments, final rest padded to ``duration_s``."""
    config = copy.deepcopy(load_case_config(config_path))
    maneuver = copy.deepcopy(config["bench"]["maneuvers"]["train"])
    total_s = sum(segment["duration_s"] for segment in maneuver["segments"])
    if total_s > duration_s:
        raise ValueError(f"--duration-s {duration_s}: shorter than the train maneuver ({total_s} s)")
    maneuver["segments"][-1]["duration_s"] += duration_s - total_s
    config["bench"]["maneuvers"] = {"benchmark": maneuver}
    if substeps is not None:
        config["bench"]["substeps"] = substeps
    return config


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", type=Path, default=ROOT / "config" / "config.yaml")
    parser.add_argument("--duration-s", type=float, default=25.0)
    parser.add_argument("--substeps", type=int, default=None)
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING)
    config = extended_config(args.config, args.duration_s, args.substeps)
    with tempfile.TemporaryDirectory() as folder:
        start = time.perf_counter()
        truth = emulate_bench(config, "benchmark", Path(folder) / "benchmark.mf4",
                              Path(folder) / "benchmark.truth.json", check_spread_of_maneuvers=False)
        total_s = time.perf_counter() - start
        mdf_bytes = (Path(folder) / "benchmark.mf4").stat().st_size
    simulated_s = truth["summary"]["duration_s"]
    loop_s = truth["summary"]["wall_s"]
    steps = simulated_s * truth["pwm_frequency_hz"]
    result = {
        "simulated_s": simulated_s,
        "substeps": truth["substeps"],
        "effects": [effect["name"] for effect in truth["effects"]],
        "loop_wall_s": round(loop_s, 3),
        "total_wall_s": round(total_s, 3),
        "control_steps_per_s": round(steps / loop_s),
        "mdf_bytes": mdf_bytes,
        "realtime_factor": round(simulated_s / loop_s, 3),
        "realtime_factor_with_output": round(simulated_s / total_s, 3),
    }
    print(f"emulated {simulated_s:.1f} s ({steps:.0f} control steps, {truth['substeps']} RK4 sub-steps each) "
          f"in {loop_s:.2f} s loop / {total_s:.2f} s total")
    print(json.dumps(result))


if __name__ == "__main__":
    main()
