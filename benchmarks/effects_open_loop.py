"""Open loop of the FMU plus the diagnosed effects: the effects evaluated by the C step loop against the same
effects called back into Python at every RK4 stage, side by side in one run.

Loads a finished case's calibrated FMU and diagnosed model (``results/<case>/diagnosis/diagnosed_model.pkl``,
rule ``diagnose``) and simulates it open loop over the whole of each given ingested maneuver from its measured
initial state, the way the diagnosis' held-out check and the evaluation simulate it, once with the additive
effect terms as the C effect program (``CorrectedModel.correction()``, the default) and once with the Python
callback per stage (the ``CorrectedModel`` itself). Prints per maneuver the wall time of each (median of
``--repeats``), their ratio, and the largest difference of the states (0 when both give the same numbers), and
a JSON object with the same figures; ``--markdown FILE`` writes the table as Markdown (for the docs:
``python -m hybridfmu.evaluation.measured_blocks --block effects_open_loop=FILE``).

    python benchmarks/effects_open_loop.py [--config config/config.yaml] [--maneuvers train validation]
        [--repeats 3] [--markdown FILE]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import numpy as np

from hybridfmu.config import check_config_file
from hybridfmu.data.roles import case_roles
from hybridfmu.diagnosis.corrected_model import simulate
from hybridfmu.diagnosis.export import load_diagnosed
from hybridfmu.diagnosis.refit import parameters_set
from hybridfmu.fmu import load_fmu, simulate_open_loop
from hybridfmu.training.measured import initial_state, load_calibration, read_measured


def open_loop(diagnosed, fmu, helper, time_s: np.ndarray, u: np.ndarray, x0: np.ndarray, in_c: bool) -> np.ndarray:
    """States (T, n_x) of the FMU plus the effects; the additive terms in C (``in_c``) or called back per stage."""
    corrected = diagnosed.corrected(helper)
    dt_s = float(np.median(np.diff(time_s)))
    correction = corrected.correction() if in_c else (corrected if corrected.has_correction else None)
    with parameters_set([fmu, helper], diagnosed.parameters), corrected.parameters_applied(fmu):
        return simulate(fmu, simulate_open_loop, time_s, corrected.inputs(u, dt_s), x0, correction)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", default="config/config.yaml")
    parser.add_argument("--maneuvers", nargs="+", default=["train", "validation"],
                        help="ingested maneuvers to simulate")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--markdown", type=Path, default=None, help="write the table as Markdown to this file")
    args = parser.parse_args()

    config = check_config_file(args.config)
    results = Path(config.get("results_dir", "results")) / config["case"]
    fmu_path = config["fmu"].get("path") or results / "fmu" / f"{config['fmu']['model_name']}.fmu"
    calibration = load_calibration(results / "calibration" / "calibration.json")
    diagnosed = load_diagnosed(results / "diagnosis" / "diagnosed_model.pkl")
    roles = case_roles(config)
    report: dict[str, dict[str, float]] = {}
    parameters = dict(calibration.parameters) or None
    with load_fmu(fmu_path, parameters=parameters) as fmu, load_fmu(fmu_path, parameters=parameters) as helper:
        program = diagnosed.corrected(helper).effect_program()
        heading = (f"Case `{config['case']}`, the FMU with its diagnosed effects and parameter errors "
                   f"({', '.join(diagnosed.effects)}; {'no' if program is None else len(program.terms)} additive "
                   "term(s) evaluated at every RK4 stage)")
        print(heading)
        for maneuver in args.maneuvers:
            measured = read_measured(results / "data" / f"{maneuver}.parquet", roles)
            x0 = diagnosed.initial_state(initial_state(fmu, measured.x[0], roles, calibration, maneuver,
                                                       config.get("maneuvers")), maneuver)
            walls: dict[bool, list[float]] = {True: [], False: []}
            states: dict[bool, np.ndarray] = {}
            for _ in range(args.repeats):
                for in_c in (True, False):
                    started = time.perf_counter()
                    states[in_c] = open_loop(diagnosed, fmu, helper, measured.time_s, measured.u, x0, in_c)
                    walls[in_c].append(time.perf_counter() - started)
            c_s, python_s = statistics.median(walls[True]), statistics.median(walls[False])
            difference = float(np.nanmax(np.abs(states[True] - states[False])))
            same = bool(np.array_equal(states[True], states[False], equal_nan=True))
            simulated_s = float(measured.time_s[-1] - measured.time_s[0])
            report[maneuver] = {"simulated_s": simulated_s, "c_s": c_s, "python_s": python_s,
                                "speedup": python_s / c_s, "max_state_difference": difference, "identical": same}
            print(f"{maneuver}: {simulated_s:.2f} s simulated; effects in C {c_s:.3f} s, called back per stage "
                  f"{python_s:.3f} s (x{python_s / c_s:.1f}); largest state difference {difference:.3g}"
                  f"{' (identical)' if same else ''}")
    if args.markdown:
        lines = [f"{heading}: open loop over whole maneuvers, median of {args.repeats} run(s), one core "
                 "(`benchmarks/effects_open_loop.py`):", "",
                 "| maneuver | simulated | terms in C | terms called back per RK4 stage | speed-up | largest state "
                 "difference |", "|---|---|---|---|---|---|"]
        for maneuver, figures in report.items():
            lines.append(f"| {maneuver} | {figures['simulated_s']:.1f} s | {figures['c_s']:.3g} s | "
                         f"{figures['python_s']:.3g} s | ×{figures['speedup']:.1f} | "
                         f"{'0 (identical)' if figures['identical'] else format(figures['max_state_difference'], '.3g')}"
                         " |")
        args.markdown.parent.mkdir(parents=True, exist_ok=True)
        args.markdown.write_text("\n".join(lines) + "\n")
    print(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
