"""Open-loop speed of a finished case's hybrid: its rollout in C (the physical layer's effects installed in the C
loop, ``PhysicsModel.neural_rollout``) against the NumPy engine (the effects evaluated in Python per solver
stage), side by side in one run on the same maneuver.

Loads the hybrid the case's search chose (``results/<case>/hybrid/best.json``; a hybrid that is its physical
layer is simulated as the FMU + effects and is not timed here) and simulates the first ``--seconds`` of a
maneuver (``--maneuver``, default validation) open loop from its measured initial state with each engine
(``--repeats`` runs each, the median). Prints simulated seconds per wall second, the ratio, and the largest
difference between the two trajectories relative to each state's range; ``--markdown FILE`` writes them as a
table for the docs.

    python benchmarks/hybrid_rollout.py [--config config/config.yaml] [--maneuver validation] [--seconds 2]
        [--repeats 3] [--markdown FILE]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import numpy as np

from hybridfmu.api.stages import case_roles
from hybridfmu.config import case_fmu_path, case_results_dir, check_config_file
from hybridfmu.io import write_text_atomic
from hybridfmu.training.inference import (diagnosed_simulator, load_trained_neural_fmu, physical_layer,
                                          simulate_neural_fmu)
from hybridfmu.training.measured import initial_state, load_calibration, read_measured

ENGINES = {"c": "adjoint_c", "numpy": "adjoint_numpy"}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", default="config/config.yaml")
    parser.add_argument("--maneuver", default="validation")
    parser.add_argument("--seconds", type=float, default=2.0, help="simulated time per run (s)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--markdown", type=Path, default=None, help="write the figures as Markdown to this file")
    args = parser.parse_args()

    config = check_config_file(args.config)
    results, fmu_path = case_results_dir(config), case_fmu_path(config)
    calibration = load_calibration(results / "calibration" / "calibration.json")
    hybrid = load_trained_neural_fmu(results / "hybrid" / "best.json", fmu_path, dict(calibration.parameters),
                                     results / "diagnosis" / "diagnosed_model.pkl")
    if diagnosed_simulator(hybrid) is not None:
        raise SystemExit(f"{results / 'hybrid' / 'best.json'}: the chosen hybrid is its physical layer, simulated "
                         "as the FMU + effects; nothing of the hybrid's rollout to time")
    roles = case_roles(config)
    measured = read_measured(results / "data" / f"{args.maneuver}.parquet", roles)
    n = min(measured.time_s.size, int(round(args.seconds / hybrid.spec.sample_period_s)) + 1)
    time_s, u = measured.time_s[:n], measured.u[:n]
    x0 = initial_state(hybrid.fmu.rhs.model, measured.x[0], roles, calibration, args.maneuver, config["maneuvers"])
    x0 = physical_layer(hybrid).diagnosed.initial_state(x0, args.maneuver)
    simulated_s = float(time_s[-1] - time_s[0])
    print(f"case {config['case']}: hybrid on {args.maneuver}, {simulated_s:.3f} s simulated per run, "
          f"{args.repeats} runs per engine", flush=True)
    rates, states = {}, {}
    for name, engine in ENGINES.items():
        walls = []
        for _ in range(args.repeats):
            started = time.perf_counter()
            states[name] = simulate_neural_fmu(hybrid, time_s, u, x0, engine=engine)
            walls.append(time.perf_counter() - started)
        rates[name] = simulated_s / statistics.median(walls)
        print(f"{name:6s} {rates[name]:9.3f} simulated s per wall s", flush=True)
    scale = np.maximum(np.ptp(states["numpy"], axis=0), 1e-300)
    deviation = float(np.max(np.abs(states["c"] - states["numpy"]) / scale))
    print(f"C over NumPy: x{rates['c'] / rates['numpy']:.1f}; largest difference {deviation:.2e} of a state's range")
    if args.markdown:
        write_text_atomic(args.markdown, "\n".join([
            f"Case `{config['case']}`, its hybrid open loop over the first {simulated_s:.3g} s of `{args.maneuver}` "
            f"from the measured state, median of {args.repeats} run(s) per engine, one process "
            "(`benchmarks/hybrid_rollout.py`):", "",
            "| engine | simulated s per wall s | against the NumPy engine |", "|---|---|---|",
            f"| C loop, the effects installed in it | {rates['c']:.3g} | ×{rates['c'] / rates['numpy']:.3g} |",
            f"| NumPy, the effects in Python per solver stage | {rates['numpy']:.3g} | ×1 |", "",
            f"Largest difference of the two trajectories: {deviation:.2g} of a state's range."]) + "\n")
    print(json.dumps({"config": args.config, "maneuver": args.maneuver, "simulated_s": simulated_s,
                      "simulated_s_per_wall_s": rates, "c_over_numpy": rates["c"] / rates["numpy"],
                      "max_relative_difference": deviation}))


if __name__ == "__main__":
    main()
