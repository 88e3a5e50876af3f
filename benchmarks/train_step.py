"""Training throughput of the neural FMU: simulated sample-steps per second (forward + backward, one core).

Builds the demo IPBMotor FMU into a temporary folder, wraps it in the bridge's FmuRhs, and times one
training step's rollout and gradient (RK4 on the 10 kHz grid, windows of 0.02 s) at B = 1, 4 (the demo's
batch) and 64 windows per batch, side by side: the discrete adjoint used in training (``adjoint``: forward pass
and reverse sweep in C, ``hybridfmu.fmu.neural``), the same adjoint with its stages in NumPy through the bridge's
derivatives-and-Jacobians kernel (``adjoint_numpy``) and as torch operations (``adjoint_torch``), plain
autograd through the hand-written RK4, and the library: torchdiffeq's fixed-grid RK4 with backpropagation through
its steps (``torchdiffeq``) and with its adjoint (``torchdiffeq_adjoint``). ``--markdown FILE`` writes the table
for the documentation (``python -m hybridfmu.evaluation.measured_blocks --block train_step=FILE``).
Prints a table; the last line is a JSON object (``samples_per_s_b1``, ``samples_per_s_b64`` of the training
path, and every row as ``<gradients>_w<width>_d<depth>_b<B>``).

    python benchmarks/train_step.py [--repeats 5] [--window-s 0.02]
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from hybridfmu.fmu import FmuRhs, load_fmu
from hybridfmu.fmu.build import build_fmu
from hybridfmu.model import NeuralFmu, NeuralFmuSpec
from hybridfmu.training.solver import rollout

SAMPLE_PERIOD_S = 1e-4


def synthetic_inputs(n_samples: int, seed: int) -> np.ndarray:
    """Duty cycles of a rotating voltage vector at a drifting speed, 12 V, a slowly varying load: (T, 5)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_samples) * SAMPLE_PERIOD_S
    angle = 4 * np.cumsum(200 + 50 * np.sin(2 * np.pi * 3 * t)) * SAMPLE_PERIOD_S
    duties = [0.5 + 0.2 * np.cos(angle - k * 2 * np.pi / 3) + 0.005 * rng.standard_normal(n_samples) for k in range(3)]
    return np.stack(duties + [12 + 0.05 * rng.standard_normal(n_samples), 0.5 + 0.2 * np.sin(2 * np.pi * t)], axis=1)


def measure(model: NeuralFmu, batch: int, n_steps: int, repeats: int, gradients: str) -> float:
    """Median sample-steps per second of rollout + backward over ``repeats`` timed runs (after one warm-up)."""
    pad = 8
    u = torch.from_numpy(synthetic_inputs(n_steps + 2 * pad + 1 + batch, 0))
    u_seq = torch.stack([u[b:b + n_steps + 2 * pad + 1] for b in range(batch)])
    x0 = torch.tensor([[0.5, 10.0, 5.0, 150.0]], dtype=torch.float64).repeat(batch, 1)
    x0[:, 3] += torch.linspace(-20, 20, batch, dtype=torch.float64)
    rates = []
    for repeat in range(repeats + 1):
        model.zero_grad(set_to_none=True)
        start = time.perf_counter()
        states = rollout(model, u_seq, pad, x0, n_steps, gradients=gradients)
        (states[:, 1:, 2].abs().mean() + 1e-2 * states[:, 1:, 3].abs().mean()).backward()
        elapsed = time.perf_counter() - start
        if repeat > 0:
            rates.append(batch * n_steps / elapsed)
    return statistics.median(rates)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--window-s", type=float, default=0.02)
    parser.add_argument("--markdown", type=Path, default=None, help="write the table as Markdown to this file")
    args = parser.parse_args()
    torch.set_num_threads(1)
    n_steps = int(round(args.window_s / SAMPLE_PERIOD_S))
    with tempfile.TemporaryDirectory(prefix="hybridfmu-bench-") as tmp:
        fmu_model = load_fmu(build_fmu("IPBMotor", Path(tmp) / "IPBMotor.fmu"))
        rhs = FmuRhs(fmu_model)
        x = np.tile([0.5, 10.0, 5.0, 150.0], (2000, 1)) + np.random.default_rng(1).normal(0, 1, (2000, 4))
        u = synthetic_inputs(2000, 1)
        xdot = fmu_model.derivatives(x, u)
        stats = {"x_mean": x.mean(0).tolist(), "x_std": x.std(0).tolist(), "u_mean": u.mean(0).tolist(),
                 "u_std": u.std(0).tolist(), "xdot_mean": xdot.mean(0).tolist(), "xdot_std": xdot.std(0).tolist()}
        rows = []
        results = {}
        for width, depth in ((8, 2), (32, 4)):
            spec = NeuralFmuSpec(state_names=fmu_model.state_names, input_names=fmu_model.input_names,
                                 corrected_states=["omega"], ann_states=fmu_model.state_names,
                                 ann_inputs=fmu_model.input_names, ann_derivatives=fmu_model.state_names,
                                 sample_period_s=SAMPLE_PERIOD_S, width=width, depth=depth, gate_opening=0.3,
                                 delay_min_s=-3e-4, delay_max_s=3e-4)
            torch.manual_seed(0)
            model = NeuralFmu(rhs, spec, stats)
            for gradients in ("adjoint", "adjoint_numpy", "adjoint_torch", "autograd", "torchdiffeq",
                              "torchdiffeq_adjoint"):
                for batch in (1, 4, 64):
                    repeats = args.repeats if gradients == "adjoint" else max(1, args.repeats // 2)
                    rate = measure(model, batch, n_steps, repeats, gradients)
                    rows.append((f"{width}x{depth}", gradients, batch, rate))
                    results[f"{gradients}_w{width}_d{depth}_b{batch}"] = rate
    print(f"neural FMU training step, IPBMotor FMU through FmuRhs, RK4, window {args.window_s} s "
          f"({n_steps} steps), float64, 1 thread")
    print(f"{'MLP':>6} {'gradients':>13} {'B':>4} {'sample-steps/s':>15}")
    for mlp, gradients, batch, rate in rows:
        print(f"{mlp:>6} {gradients:>13} {batch:>4} {rate:>15,.0f}")
    summary = {"samples_per_s_b1": results["adjoint_w8_d2_b1"], "samples_per_s_b64": results["adjoint_w8_d2_b64"],
               "window_steps": n_steps, "mlp": "8x2", **results}
    if args.markdown:
        args.markdown.parent.mkdir(parents=True, exist_ok=True)
        args.markdown.write_text(markdown(rows, args.window_s, n_steps))
    print(json.dumps(summary))


#: What each gradients option of ``hybridfmu.training.solver.rollout`` is, for the Markdown table.
DESCRIPTIONS = {
    "adjoint": "discrete adjoint, forward pass and reverse sweep in C (training's default)",
    "adjoint_numpy": "discrete adjoint, stages in NumPy",
    "adjoint_torch": "discrete adjoint, stages as torch operations",
    "autograd": "autograd through the hand-written RK4",
    "torchdiffeq": "torchdiffeq.odeint, fixed-grid RK4, autograd through its steps",
    "torchdiffeq_adjoint": "torchdiffeq.odeint_adjoint, fixed-grid RK4",
}


def markdown(rows: list[tuple[str, str, int, float]], window_s: float, n_steps: int) -> str:
    """The table as Markdown: sample-steps/s per MLP, method and batch, and each method's ratio to torchdiffeq."""
    batches = sorted({batch for _, _, batch, _ in rows})
    rate = {(mlp, gradients, batch): value for mlp, gradients, batch, value in rows}
    lines = [f"Training step (rollout + gradient) of the demo's neural FMU around the IPBMotor FMU, RK4 on the "
             f"10 kHz grid, windows of {window_s} s ({n_steps} steps), one core, in simulated sample-steps/s "
             f"(`benchmarks/train_step.py`; ratio: against torchdiffeq.odeint at the same B):", "",
             "| MLP | method | " + " | ".join(f"B = {b}" for b in batches) + " |",
             "|---|---|" + "---|" * len(batches)]
    for mlp in dict.fromkeys(m for m, _, _, _ in rows):
        for gradients in dict.fromkeys(g for m, g, _, _ in rows if m == mlp):
            cells = []
            for batch in batches:
                value, library = rate.get((mlp, gradients, batch)), rate.get((mlp, "torchdiffeq", batch))
                ratio = f" (×{value / library:.3g})" if value and library and gradients != "torchdiffeq" else ""
                cells.append(f"{value:,.0f}{ratio}" if value else "–")
            lines.append(f"| {mlp} | {DESCRIPTIONS.get(gradients, gradients)} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
