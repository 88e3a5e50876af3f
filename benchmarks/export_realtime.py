"""Simulation speed of the exported FMUs in FMPy's co-simulation loop, against real time.

For each exported model of a finished run (``--results``, e.g. ``results/ipb``: the records ``export/<model>.json``
of rule ``export``) and, beside them, the case's FMU alone exported the same way (the same wrapper, grid and
solver, no ANN, no effects: ``hybridfmu.export.content.plain_content``), ``fmpy.simulate_fmu`` runs the FMU over
the first ``--duration-s`` seconds of a maneuver's logged inputs (``--maneuver``, default the records' first
check maneuver) with a communication step of ``--step-s`` (default 1 ms, or the model's sample period if longer).
The models run in turn, ``--repeats`` times, so that all of them share the machine's load; the figure is the
median of simulated seconds per wall second (above 1: faster than real time), and its ratio to the FMU alone.

Prints a table and, last line, a JSON object; ``--markdown FILE`` writes the table for the docs
(``python -m hybridfmu.evaluation.measured_blocks --block export_realtime=FILE``).

    python benchmarks/export_realtime.py --config config/config.yaml [--results results/ipb] [--duration-s 5]
        [--step-s 0.001] [--repeats 3] [--markdown FILE]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from hybridfmu.config import case_fmu_path, case_results_dir, load_case_config
from hybridfmu.data.roles import case_roles
from hybridfmu.export.content import plain_content
from hybridfmu.export.package import write_exported_fmu
from hybridfmu.export.stage import model_content
from hybridfmu.io import read_json, write_text_atomic
from hybridfmu.training.measured import read_measured


def run_once(fmu: Path, time_s: np.ndarray, u: np.ndarray, inputs: list[str], outputs: list[str],
             step_s: float) -> float:
    """Wall time (s) of one FMPy co-simulation over ``time_s`` with the inputs held over each step."""
    from fmpy import simulate_fmu

    signals = np.zeros(len(time_s), dtype=[("time", float)] + [(name, float) for name in inputs])
    signals["time"] = time_s - time_s[0]
    for column, name in enumerate(inputs):
        signals[name] = u[:, column]
    start = time.perf_counter()
    simulate_fmu(str(fmu), start_time=0.0, stop_time=float(time_s[-1] - time_s[0]), step_size=step_s,
                 output_interval=step_s, input=signals, output=outputs)
    return time.perf_counter() - start


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", default="config/config.yaml", help="the case config of the finished run")
    parser.add_argument("--results", help="the case's results folder (default <results_dir>/<case>)")
    parser.add_argument("--maneuver", help="the maneuver whose logged inputs drive the models")
    parser.add_argument("--duration-s", type=float, default=5.0)
    parser.add_argument("--step-s", type=float, default=1e-3)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--markdown", help="write the table as Markdown to this file")
    args = parser.parse_args(argv)
    config = load_case_config(args.config)
    results = Path(args.results) if args.results else case_results_dir(config)
    fmu_path = (results / "fmu" / f"{config['fmu']['model_name']}.fmu" if config["fmu"]["source"] == "build"
                else case_fmu_path(config))
    records = {path.stem: read_json(path) for path in sorted((results / "export").glob("*.json"))}
    if not records:
        print(f"{results}/export: no exported models (run the workflow's rule export first)", file=sys.stderr)
        return 1
    first = next(iter(records.values()))
    maneuver = args.maneuver or first["checks"][0]["maneuver"]
    measured = read_measured(results / "data" / f"{maneuver}.parquet", case_roles(config))
    sample_s = float(first["sample_period_s"])
    step_s = max(args.step_s, sample_s)
    steps_per_sample = round(step_s / sample_s)
    n = min(measured.time_s.size, int(round(args.duration_s / sample_s)) + 1)
    rows = np.arange(0, n, steps_per_sample)
    time_s, u = measured.time_s[rows], measured.u[rows]
    with tempfile.TemporaryDirectory(prefix="export-realtime-") as folder:
        reference = model_content("neural_fmu", results / "hpo" / "best.json", fmu_path,
                                  results / "calibration" / "calibration.json")
        plain = Path(folder) / "fmu_alone.fmu"
        write_exported_fmu(plain_content(reference), "fmu_alone", fmu_path, plain,
                           {"case": config["case"], "model": "the FMU alone"}, "benchmark")
        models = {"the FMU alone": plain,
                  **{record["model"]: results / "export" / Path(record["fmu"]).name for record in records.values()}}
        inputs, outputs = first["inputs"], first["states"]
        walls: dict[str, list[float]] = {name: [] for name in models}
        for _ in range(args.repeats):
            for name, fmu in models.items():
                walls[name].append(run_once(fmu, time_s, u, inputs, outputs, step_s))
    simulated_s = float(time_s[-1] - time_s[0])
    speed = {name: simulated_s / statistics.median(values) for name, values in walls.items()}
    base = speed["the FMU alone"]
    lines = [f"Exported models of case `{config['case']}` in FMPy's co-simulation loop (`fmpy.simulate_fmu`), "
             f"{simulated_s:g} s of `{maneuver}`'s logged inputs, communication step {step_s * 1e3:g} ms, median of "
             f"{args.repeats} runs in turn (`benchmarks/export_realtime.py`):", "",
             "| model | simulated s per wall s (× real time) | against the FMU alone |", "|---|---|---|"]
    for name, value in speed.items():
        lines.append(f"| {name} | {value:.3g} | ×{value / base:.2f} |")
    text = "\n".join(lines)
    print(text)
    if args.markdown:
        write_text_atomic(args.markdown, text + "\n")
    print(json.dumps({"case": config["case"], "maneuver": maneuver, "simulated_s": simulated_s, "step_s": step_s,
                      "wall_s": walls, "realtime_factor": speed}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
