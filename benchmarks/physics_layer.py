"""Cost of a hybrid's physical layer: derivative evaluations per second, the FMU alone against the FMU plus the
diagnosed effects, side by side in one run.

Loads a finished case's calibrated FMU and diagnosed model (``results/<case>/diagnosis/diagnosed_model.pkl``,
rule ``diagnose``), takes B random rows (states and inputs) of the prepared training data (``hpo/prepared``), and times per call (median of ``--repeats`` runs of ``--calls`` calls each):

- ``fmu``: the FMU's batched derivatives (the bridge's kernel);
- ``terms``: the effects' additive terms alone (``CorrectedModel.additive_batch``), and ``terms_per_member``:
  the same with a joint effect's members evaluated one by one (``joint_batches=False``);
- ``physics``: the physical layer's derivatives (FMU + terms, one solver stage of a validation rollout);
- ``physics_jacobians``: derivatives and Jacobians (one stage of a training rollout), and
  ``physics_coefficients``: the same with the coefficients' Jacobian (a stage when the coefficients train), the
  terms and their differences in C (``FmuModel.effect_jacobians_kernel``); ``*_numpy``: the same in NumPy
  (``PhysicsModel.terms_in_c = False``), side by side.

Prints one line per row and a JSON object with the microseconds per call, the ratios to ``fmu`` and the NumPy
form's time over the C form's (``numpy_over_c``).

    python benchmarks/physics_layer.py [--config config/config.yaml] [--batch 4] [--calls 2000] [--repeats 5]
        [--markdown FILE]

``--markdown FILE`` writes the training rows for the docs (``python -m hybridfmu.evaluation.measured_blocks --block
physics_layer=FILE``).
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import numpy as np

from hybridfmu.config import check_config_file
from hybridfmu.diagnosis.corrected_model import CorrectedModel
from hybridfmu.io import write_text_atomic
from hybridfmu.model.physics import physics_model
from hybridfmu.training.data import ManeuverArrays
from hybridfmu.training.measured import load_calibration


def time_per_call_us(functions: dict, calls: int, repeats: int) -> dict[str, float]:
    """Per function, the median over ``repeats`` of the mean wall time per call (µs) of ``calls`` calls; the
    functions take turns in every repeat, so that all of them share the machine's load."""
    runs: dict[str, list[float]] = {name: [] for name in functions}
    for _ in range(repeats):
        for name, function in functions.items():
            started = time.perf_counter()
            for _ in range(calls):
                function()
            runs[name].append((time.perf_counter() - started) / calls * 1e6)
    return {name: statistics.median(values) for name, values in runs.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", default="config/config.yaml")
    parser.add_argument("--batch", type=int, default=4, help="rows per call (windows or segments side by side)")
    parser.add_argument("--calls", type=int, default=2000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--markdown", help="write the training rows (C against NumPy) as Markdown to this file")
    args = parser.parse_args()

    config = check_config_file(args.config)
    results = Path(config.get("results_dir", "results")) / config["case"]
    fmu_path = config["fmu"].get("path") or results / "fmu" / f"{config['fmu']['model_name']}.fmu"
    calibration = load_calibration(results / "calibration" / "calibration.json")
    physics = physics_model(fmu_path, calibration.parameters, results / "diagnosis" / "diagnosed_model.pkl")
    train = ManeuverArrays.load(results / "hpo" / "prepared" / "train.npz")
    rng = np.random.default_rng(args.seed)
    rows = rng.integers(0, train.u.shape[0], args.batch)
    u = np.ascontiguousarray(train.u[rows], dtype=float)
    x = np.ascontiguousarray(train.x_init[rows], dtype=float)
    per_member = CorrectedModel(physics.diagnosed.terms, physics.diagnosed.problem, physics.helper,
                                joint_batches=False, hold=physics.diagnosed.hold)
    in_numpy = physics_model(fmu_path, calibration.parameters, results / "diagnosis" / "diagnosed_model.pkl")
    in_numpy.terms_in_c = False
    np.testing.assert_allclose(per_member.additive_batch(x, u), physics.corrected.additive_batch(x, u),
                               rtol=1e-12, atol=1e-12)
    fmu_kernel = physics.fmu.derivatives_kernel(args.batch) if hasattr(physics.fmu, "derivatives_kernel") \
        else physics.fmu.derivatives
    rows_timed = {
        "fmu": lambda: fmu_kernel(x, u),
        "terms": lambda: physics.corrected.additive_batch(x, u),
        "terms_per_member": lambda: per_member.additive_batch(x, u),
        "physics": lambda: physics.derivatives(x, u),
        "physics_jacobians": lambda: physics.derivatives_and_jacobians(x, u),
        "physics_jacobians_numpy": lambda: in_numpy.derivatives_and_jacobians(x, u),
        "physics_coefficients": lambda: physics.derivatives_jacobians_and_coefficient_jacobian(x, u),
        "physics_coefficients_numpy": lambda: in_numpy.derivatives_jacobians_and_coefficient_jacobian(x, u),
    }
    print(f"case {config['case']}: the FMU plus {', '.join(physics.effects)}; B = {args.batch}, "
          f"{args.calls} calls x {args.repeats}", flush=True)
    for function in rows_timed.values():  # warm: the C programs are laid out at the first call
        function()
    timings = time_per_call_us(rows_timed, args.calls, args.repeats)
    for name, value in timings.items():
        print(f"{name:26s} {value:9.1f} µs/call  {1e6 / value:10.0f} calls/s  "
              f"x{value / timings['fmu']:.1f} the FMU's time", flush=True)
    if args.markdown:
        write_text_atomic(args.markdown, training_table(config["case"], args.batch, args.calls, args.repeats,
                                                        timings))
    print(json.dumps({"config": args.config, "batch": args.batch, "us_per_call": timings,
                      "ratio_to_fmu": {k: v / timings["fmu"] for k, v in timings.items()},
                      "joint_over_per_member": timings["terms"] / timings["terms_per_member"],
                      "numpy_over_c": {name: timings[f"{name}_numpy"] / timings[name]
                                       for name in ("physics_jacobians", "physics_coefficients")}}))


def training_table(case: str, batch: int, calls: int, repeats: int, timings: dict[str, float]) -> str:
    """The training's call per solver stage, the effect terms in C against NumPy, as Markdown."""
    lines = [f"Case `{case}`, its physical layer's call per solver stage of a training rollout, B = {batch} rows of "
             f"the prepared training data, median of {repeats} runs of {calls} calls taking turns "
             "(`benchmarks/physics_layer.py`):", "",
             "| call | terms in C | terms in NumPy | speed-up |", "|---|---|---|---|"]
    for name, label in (("physics_jacobians", "derivatives and Jacobians"),
                        ("physics_coefficients", "derivatives, Jacobians and the coefficients' Jacobian")):
        c, numpy = timings[name], timings[f"{name}_numpy"]
        lines.append(f"| {label} | {c:.0f} µs | {numpy:.0f} µs | ×{numpy / c:.2f} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
