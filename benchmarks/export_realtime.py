"""Simulation speed of the exported FMUs in FMPy's co-simulation loop, against real time.

Each trained model of a finished run (``--results``, e.g. ``results/ipb``; the neural FMU, the FMU + diagnosed
effects, and the hybrid where the run has one) is exported as rule ``export`` exports it (``hybridfmu.api.export_fmu``,
into a temporary folder) and, beside them, the case's FMU alone the same way (the same wrapper, grid and solver, no
ANN, no effects: ``hybridfmu.export.content.plain_content``); ``fmpy.simulate_fmu`` runs each over the first
``--duration-s`` seconds of a maneuver's logged inputs (``--maneuver``, default the first test maneuver) with a
communication step of ``--step-s`` (default 1 ms, or the model's sample period if longer).
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
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from hybridfmu import api
from hybridfmu.data.signals import signal_array
from hybridfmu.export.content import plain_content
from hybridfmu.export.package import write_exported_fmu
from hybridfmu.export.stage import model_content
from hybridfmu.io import write_text_atomic

#: The table's names of the models.
MODEL_LABELS = {"neural_fmu": "neural FMU", "fmu_effects": "FMU + diagnosed effects",
                "hybrid": "hybrid (FMU + effects + ANN)"}


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
    case = api.load_case(args.config)
    run = api.load_run(case, args.results)
    results = run.results_dir
    maneuver = args.maneuver or next(name for name, item in case.config["maneuvers"].items() if item["role"] == "test")
    frame = pd.read_parquet(results / "data" / f"{maneuver}.parquet")
    models = ["neural_fmu", "fmu_effects"] + (["hybrid"] if "hybrid" in run.best else [])
    with tempfile.TemporaryDirectory(prefix="export-realtime-") as folder:
        exported = {model: api.export_fmu(case, model, Path(folder) / f"{model}.fmu", run) for model in models}
        reference = model_content("neural_fmu", results / "hpo" / "best.json", api.fmu_file(case),
                                  run.calibration_path)
        plain = Path(folder) / "fmu_alone.fmu"
        write_exported_fmu(plain_content(reference), "fmu_alone", api.fmu_file(case), plain,
                           {"case": case.name, "model": "the FMU alone"}, "benchmark")
        fmus = {"the FMU alone": plain, **{MODEL_LABELS[model]: path for model, path in exported.items()}}
        sample_s = float(reference.sample_period_s)
        step_s = max(args.step_s, sample_s)
        every = int(round(step_s / sample_s))
        n = min(len(frame), int(round(args.duration_s / sample_s)) + 1)
        rows = np.arange(0, n, every)
        time_s = frame["time_s"].to_numpy(dtype=float)[rows]
        u = signal_array(frame, case.roles.input_signals)[rows]
        inputs, outputs = list(reference.inner.input_names), list(reference.inner.state_names)
        walls: dict[str, list[float]] = {name: [] for name in fmus}
        for _ in range(args.repeats):
            for name, fmu in fmus.items():
                walls[name].append(run_once(fmu, time_s, u, inputs, outputs, step_s))
    simulated_s = float(time_s[-1] - time_s[0])
    speed = {name: simulated_s / statistics.median(values) for name, values in walls.items()}
    base = speed["the FMU alone"]
    lines = [f"Exported models of case `{case.name}` in FMPy's co-simulation loop (`fmpy.simulate_fmu`), "
             f"{simulated_s:g} s of `{maneuver}`'s logged inputs, communication step {step_s * 1e3:g} ms, median of "
             f"{args.repeats} runs in turn (`benchmarks/export_realtime.py`):", "",
             "| model | simulated s per wall s (× real time) | against the FMU alone |", "|---|---|---|"]
    for name, value in speed.items():
        lines.append(f"| {name} | {value:.3g} | ×{value / base:.2f} |")
    text = "\n".join(lines)
    print(text)
    if args.markdown:
        write_text_atomic(args.markdown, text + "\n")
    print(json.dumps({"case": case.name, "maneuver": maneuver, "simulated_s": simulated_s, "step_s": step_s,
                      "wall_s": walls, "realtime_factor": speed}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
