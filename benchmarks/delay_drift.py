"""Where the training loss takes the learned input delays when nothing else can move.

Builds the case's neural FMU with the ANN shut (output layer zero, gate g_A = 0 and left out of the
optimizer), so the model is the FMU with delayed inputs, starts the delay groups at ``--start`` (s; one
value for every group, or ``group=value`` pairs) and trains only the delays with Adam at the case's
``model.input_delay.step_s`` on random windows of the prepared training data, with the case's loss weights.
With a model that lacks some physics the delays drift to absorb it: the figures show how far and where to.
``--physics`` runs the same on the hybrid's physical layer (the FMU plus the effects of the diagnosed model,
``results/<case>/diagnosis/diagnosed_model.pkl``, its time offsets included, the delays learning what remains):
whether the drift goes once the model carries the diagnosed physics; with ``--coefficients`` the effects' additive
coefficients train beside the delays (at the case's ``model.physics_coefficient_step``).

Needs a finished search's prepared data (``results/<case>/hpo/prepared``, rule ``hpo_prepare``). Prints one
line per ``--every`` steps (delays in µs, the step's loss) and a JSON object with the trajectory.

    python benchmarks/delay_drift.py [--config config/config.yaml] [--start 30e-6] [--steps 150]
        [--window-s 0.03] [--w-omega 0.5] [--seed 5] [--physics [--coefficients]]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from hybridfmu.data.roles import case_roles
from hybridfmu.config import check_config_file
from hybridfmu.fmu import FmuRhs
from hybridfmu.io import read_json
from hybridfmu.training.build import build_neural_fmu, model_spec
from hybridfmu.training.data import ManeuverArrays
from hybridfmu.training.measured import load_calibrated_fmu, load_calibration
from hybridfmu.training.optim import Adam
from hybridfmu.training.trainer import Hyperparameters, Trainer, TrainerSettings
from hybridfmu.training.trial import hybrid_arrays, hybrid_physics


def parse_start(text: str) -> float | dict[str, float]:
    """'30e-6' -> 3e-5; 'duties=30e-6,supply=0' -> {'duties': 3e-5, 'supply': 0.0}."""
    if "=" not in text:
        return float(text)
    pairs = [item.split("=", 1) for item in text.split(",") if item]
    return {name.strip(): float(value) for name, value in pairs}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", default="config/config.yaml")
    parser.add_argument("--start", default="30e-6", help="initial delay(s), s")
    parser.add_argument("--steps", type=int, default=150)
    parser.add_argument("--every", type=int, default=30)
    parser.add_argument("--window-s", type=float, default=0.03)
    parser.add_argument("--w-omega", type=float, default=None, help="loss weight of one target (w_<state>)")
    parser.add_argument("--target", default="omega", help="the target --w-omega sets")
    parser.add_argument("--seed", type=int, default=5)
    parser.add_argument("--physics", action="store_true",
                        help="the FMU plus the diagnosed effects instead of the FMU (needs rule diagnose's output)")
    parser.add_argument("--coefficients", action="store_true",
                        help="with --physics: also train the effects' coefficients (model.physics_coefficient_step)")
    args = parser.parse_args()

    config = check_config_file(args.config)
    roles = case_roles(config)
    results = Path(config.get("results_dir", "results")) / config["case"]
    train = ManeuverArrays.load(results / "hpo" / "prepared" / "train.npz")
    statistics = read_json(results / "hpo" / "prepared" / "statistics.json")
    fmu_path = config["fmu"].get("path") or results / "fmu" / f"{config['fmu']['model_name']}.fmu"
    calibration = load_calibration(results / "calibration" / "calibration.json")
    fmu = load_calibrated_fmu(fmu_path, calibration)
    model_config = config["model"]
    physics = None
    if args.physics:
        physics = hybrid_physics({**model_config, "physics_terms": "from_diagnosis"}, fmu_path,
                                 calibration.parameters, results / "diagnosis" / "diagnosed_model.pkl")
        train = hybrid_arrays(train, physics)
        print(f"physical layer: the FMU plus {', '.join(physics.effects)}", flush=True)
    step_s = model_config["input_delay"].get("step_s")
    if step_s is None:
        raise SystemExit(f"{args.config}: model.input_delay.step_s is not set; this benchmark trains the delays at it")
    start = parse_start(args.start)
    spec = model_spec(model_config, fmu, train.sample_period_s, 8, 2, 0.0, delay_init_s=start,
                      physics_effects=None if physics is None else physics.effects)
    model = build_neural_fmu(FmuRhs(fmu if physics is None else physics), spec, statistics, args.seed)
    hyper = Hyperparameters(lr=0.0, beta1=0.9, beta2=0.999, window_s=args.window_s, loss="MAE", width=8, depth=2,
                            gate_opening=0.0, batch_windows=4)
    overrides = {} if args.w_omega is None else {args.target: args.w_omega}
    trainer = Trainer(model, train, hyper, statistics, TrainerSettings(), args.seed, roles.weights_with(overrides))
    groups = [{"params": [model.delay.raw], "lr": step_s / spec.delay_scale_s}]
    if args.coefficients:
        if model.fmu.coefficient_change is None:
            raise SystemExit(f"{args.config}: --coefficients needs --physics, model.physics_coefficient_step and a "
                             "physical layer with additive terms")
        groups.append({"params": [model.fmu.coefficient_change], "lr": spec.physics_coefficient_step})
    elif model.fmu.coefficient_change is not None:
        model.fmu.coefficient_change.requires_grad_(False)
    trainer.optimizer = Adam(groups, lr=0.0, betas=(0.9, 0.999))
    trajectory = [{"step": 0, "delays_us": {g: v * 1e6 for g, v in model.delay_s().items()}}]
    started = time.perf_counter()
    for step in range(1, args.steps + 1):
        result = trainer.step()
        if step % args.every == 0 or step == args.steps:
            delays = {g: v * 1e6 for g, v in model.delay_s().items()}
            trajectory.append({"step": step, "delays_us": delays, "loss": result["loss"]})
            elapsed = time.perf_counter() - started
            print(f"step {step:4d}  " + "  ".join(f"{g} {v:8.2f} µs" for g, v in delays.items())
                  + f"  loss {result['loss']:.4g}  skipped {trainer.skipped_steps}  ({step / elapsed:.1f} steps/s, "
                  f"{(args.steps - step) * elapsed / step:.0f} s left)", flush=True)
    if args.coefficients:
        for name, values in model.physics_coefficients().items():
            print(f"  {name:40s} {values['diagnosed']:12.5g} -> {values['trained']:12.5g}", flush=True)
    print(json.dumps({"config": args.config, "physics": None if physics is None else physics.effects,
                      "start_s": start, "step_s": step_s, "window_s": args.window_s,
                      "weights": roles.weights_with(overrides), "trajectory": trajectory}))


if __name__ == "__main__":
    main()
