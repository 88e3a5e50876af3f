"""A search end to end on synthetic data with the real IPBMotor FMU: prepare, plan, train rungs (resumed),
a failed trial, selection, best.json, and the inference API."""

import json
import math

import numpy as np
import pytest
import torch

from hybridfmu.data.settings import section_settings
from hybridfmu.fmu import load_fmu, simulate_open_loop
from hybridfmu.fmu.build import build_fmu
from hybridfmu.io import read_json, write_json_atomic
from hybridfmu.evaluation.baseline import run_baseline
from hybridfmu.training.finalists import score_finalists
from hybridfmu.training.hpo import plan_search, prepare_training_data, select_best, select_rung
from hybridfmu.training.inference import load_trained_neural_fmu, simulate_neural_fmu
from hybridfmu.training.checkpoint import load_checkpoint
from hybridfmu.training.trial import run_trial_rung
from test_evaluation_baseline import MANEUVERS, measured_frame, motor_roles, write_calibration

H = 1e-4
ROLES = motor_roles()


def motor_inputs(n: int, seed: int, theta0_rad: float = 5.0, pole_pairs: int = 4) -> np.ndarray:
    """(n, 5) inputs [d_a, d_b, d_c, u_dc, tau_load] of the IPBMotor: duties of a voltage vector leading the
    q-axis of a rotor that speeds up to 150 rad/s and back twice a second, 12 V with noise, a varying load."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * H
    speed = 150.0 * (0.5 - 0.5 * np.cos(2 * np.pi * 2.0 * t))
    angle_e = pole_pairs * (theta0_rad + np.cumsum(speed) * H) + np.pi / 2
    amplitude = (pole_pairs * 6e-3 * speed + 0.6) / 12.0
    duties = [0.5 + amplitude * np.cos(angle_e - k * 2 * np.pi / 3) + 0.002 * rng.standard_normal(n)
              for k in range(3)]
    return np.column_stack(duties + [12.0 + 0.05 * rng.standard_normal(n), 0.05 + 0.03 * np.sin(2 * np.pi * 1.5 * t)])


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    root = tmp_path_factory.mktemp("case")
    fmu_path = build_fmu("IPBMotor", root / "IPBMotor.fmu")
    true_motor = load_fmu(fmu_path, parameters={"J": 2.3e-4, "b": 1e-4})
    paths = {}
    for role, seed in (("train", 0), ("validation", 1)):
        n = 2500
        time_s = np.arange(n) * H
        u = motor_inputs(n, seed, theta0_rad=5.0)
        states = simulate_open_loop(true_motor, time_s, u, np.array([0.0, 0.0, 5.0, 0.0])).states
        data = root / f"{role}.parquet"
        measured_frame(time_s, u, states).to_parquet(data)
        segments = root / f"{role}.json"
        write_json_atomic(segments, {"maneuver": role, "spans_s": [[0.02, 0.12], [0.14, 0.24]], "thresholds": {},
                                     "fraction_kept": 0.8})
        paths[role] = (data, segments)
    arrays = {role: root / "prepared" / f"{role}.npz" for role in paths}
    statistics = root / "prepared" / "statistics.json"
    calibration = write_calibration(root / "calibration.json", {"theta_min": -100.0})
    prepare_training_data(fmu_path=fmu_path, calibration_path=calibration, roles=ROLES,
                          maneuvers={"train": "train", "validation": "val"}, maneuvers_config=MANEUVERS,
                          data_paths={r: p[0] for r, p in paths.items()},
                          segments_paths={r: p[1] for r, p in paths.items()}, baseline_paths={},
                          array_paths=arrays, statistics_path=statistics)
    hpo = section_settings({"R": 3, "eta": 3, "max_resource_s": 0.03, "search_space": {
        "lr": {"distribution": "loguniform", "low": 1e-3, "high": 1e-2},
        "beta1": {"distribution": "fixed", "value": 0.9}, "beta2": {"distribution": "fixed", "value": 0.999},
        "window_s": {"distribution": "uniform", "low": 0.003, "high": 0.005},
        "loss": {"distribution": "choice", "values": ["MAE", "MSE"]},
        "w_omega": {"distribution": "uniform", "low": 0.0, "high": 1.0},
        "width": {"distribution": "fixed", "value": 8}, "depth": {"distribution": "fixed", "value": 2},
        "gate_opening": {"distribution": "uniform", "low": 0.0, "high": 0.3},
        "batch_windows": {"distribution": "fixed", "value": 2}}}, "hpo")
    model = section_settings({"corrected_states": ["omega"], "end_stop": {
        "state": "theta", "rate_state": "omega", "min_parameter": "theta_min", "max_parameter": "theta_max"}}, "model")
    training = section_settings({}, "training")
    plan_path = root / "hpo" / "plan.json"
    plan_search(case="synthetic", seed=11, hpo_config=hpo, training_config=training, model_config=model,
                plan_path=plan_path, tracking_uri=None, experiment=None, roles=ROLES)
    return {"root": root, "fmu": fmu_path, "arrays": arrays, "statistics": statistics, "plan": plan_path,
            "model": model, "training": training, "calibration": calibration, "hpo": hpo}


def train(case, bracket, rung, config, plan=None):
    folder = case["root"] / "hpo" / f"b{bracket}" / f"r{rung}" / f"c{config}"
    previous = case["root"] / "hpo" / f"b{bracket}" / f"r{rung - 1}" / f"c{config}" / "checkpoint.pt"
    return run_trial_rung(
        plan_path=plan or case["plan"], bracket=bracket, rung=rung, config_index=config,
        train_arrays_path=case["arrays"]["train"], validation_arrays_path=case["arrays"]["validation"],
        statistics_path=case["statistics"], fmu_path=case["fmu"], calibration_path=case["calibration"], roles=ROLES, model_config=case["model"],
        training_config=case["training"], previous_checkpoint=previous if rung > 0 else None,
        checkpoint_path=folder / "checkpoint.pt", result_path=folder / "result.json", track=False)


def test_search_end_to_end(case):
    plan = read_json(case["plan"])
    assert [(b["bracket"], len(b["configs"]), [r["n_configs"] for r in b["rungs"]]) for b in plan["brackets"]] == [
        (1, 3, [3, 1]), (0, 2, [2])]
    hpo = case["root"] / "hpo"
    first = [train(case, 1, 0, c) for c in range(3)]
    assert all(r["status"] == "ok" and r["objective"] > 0 for r in first)
    target = plan["brackets"][0]["rungs"][0]["resource_s"]
    for result in first:  # training stops at the first step boundary at or beyond the rung's resource
        step_s = result["hyperparameters"]["batch_windows"] * round(result["hyperparameters"]["window_s"] / H) * H
        assert target - 1e-12 <= result["resource_s"] < target + step_s
    selection = select_rung(plan_path=case["plan"], bracket=1, rung=0,
                            result_paths=[hpo / f"b1/r0/c{c}/result.json" for c in range(3)],
                            selection_path=hpo / "b1/r0/selection.json")
    ranked = sorted(first, key=lambda r: r["objective"])
    assert selection["survivors"] == [ranked[0]["config"]] and not selection["last_rung"]
    survivor = selection["survivors"][0]
    resumed = train(case, 1, 1, survivor)
    assert resumed["status"] == "ok" and resumed["resource_s"] >= 0.03 - 1e-9
    assert len(resumed["validations"]) == 2 and resumed["steps"] > ranked[0]["steps"]
    checkpoint = load_checkpoint(resumed["checkpoint"])
    assert checkpoint["rung"] == 1 and checkpoint["trainer"]["used_samples"] * H == pytest.approx(resumed["resource_s"])
    select_rung(plan_path=case["plan"], bracket=1, rung=1, result_paths=[hpo / f"b1/r1/c{survivor}/result.json"],
                selection_path=hpo / "b1/r1/selection.json")

    # a configuration whose windows fit no segment fails, records why, and the search goes on
    broken = read_json(case["plan"])
    broken["brackets"][1]["configs"][1]["hyperparameters"]["window_s"] = 5.0
    broken_plan = case["root"] / "broken_plan.json"
    broken_plan.write_text(json.dumps(broken))
    ok = train(case, 0, 0, 0, plan=broken_plan)
    failed = train(case, 0, 0, 1, plan=broken_plan)
    assert failed["status"] == "failed" and "no selected segment holds a window" in failed["reason"]
    assert failed["objective"] is None and (hpo / "b0/r0/c1/checkpoint.pt").is_file()
    last = select_rung(plan_path=case["plan"], bracket=0, rung=0,
                       result_paths=[hpo / f"b0/r0/c{c}/result.json" for c in range(2)],
                       selection_path=hpo / "b0/r0/selection.json")
    assert last["n_failed"] == 1 and last["ranking"][-1]["config"] == 1 and last["survivors"] == []

    selections = [hpo / "b1/r0/selection.json", hpo / "b1/r1/selection.json", hpo / "b0/r0/selection.json"]
    best = select_best(plan_path=case["plan"], selection_paths=selections,
                       best_path=hpo / "best.json", best_model_path=hpo / "best_model.pt",
                       summary_path=hpo / "summary.json", case="synthetic")
    winner = min((resumed, ok), key=lambda r: r["objective"])
    assert best["trial_id"] == winner["trial_id"] and best["objective"] == winner["objective"]
    assert best["selection"] == {"by": "objective"}
    summary = read_json(hpo / "summary.json")
    assert len(summary["trials"]) == 6 and summary["best_trial"] == best["trial_id"]
    assert {t["status"] for t in summary["trials"]} == {"ok", "failed"}

    # the finalists (the last rungs' successful results) open loop over both whole maneuvers against the FMU
    maneuver_paths = {}
    for role, name in (("train", "train"), ("validation", "val")):
        maneuver_paths[name] = {"data": case["root"] / f"{role}.parquet", "baseline": hpo / f"baseline_{name}.parquet"}
        run_baseline(case["fmu"], case["calibration"], maneuver_paths[name]["data"], maneuver_paths[name]["baseline"],
                     hpo / f"baseline_{name}.json", ROLES, MANEUVERS, name)
    scores = score_finalists(plan_path=case["plan"], selection_paths=selections, top=5, maneuver_paths=maneuver_paths,
                             fmu_path=case["fmu"], calibration_path=case["calibration"], roles=ROLES,
                             maneuvers_config=MANEUVERS, scores_path=hpo / "finalists.json")
    assert [f["trial_id"] for f in scores["finalists"]] == [r["trial_id"] for r in sorted((resumed, ok),
                                                                                          key=lambda r: r["objective"])]
    for finalist in scores["finalists"]:
        ratios = [finalist["maneuvers"][name]["ratio"] for name in ("train", "val")]
        assert all(0 < r < 10 for r in ratios) and finalist["score"] == pytest.approx(math.sqrt(ratios[0] * ratios[1]))
    chosen = min(scores["finalists"], key=lambda f: f["score"])
    assert scores["chosen"] == chosen["trial_id"] and read_json(hpo / "finalists.json") == scores
    # one file per candidate (the workflow scores them in parallel); ranks without a finished configuration are absent
    assert read_json(hpo / "finalists" / "rank1.json")["trial_id"] == scores["finalists"][0]["trial_id"]
    assert read_json(hpo / "finalists" / "rank5.json") == {"candidate": "rank5", "absent": True}
    chosen_best = select_best(plan_path=case["plan"], selection_paths=selections, best_path=hpo / "best_chosen.json",
                              best_model_path=hpo / "best_chosen.pt", summary_path=hpo / "summary_chosen.json",
                              case="synthetic", finalists_path=hpo / "finalists.json")
    assert chosen_best["trial_id"] == chosen["trial_id"] and chosen_best["selection"]["by"] == "maneuvers"
    assert read_json(hpo / "summary_chosen.json")["best_trial"] == chosen["trial_id"]

    model = load_trained_neural_fmu(hpo / "best.json", case["fmu"], {"theta_min": -100.0})
    assert model.delay_s() == pytest.approx(best["delay_s"]) and model.gate_values() == best["gates"]
    assert model.spec.end_stop.min == -100.0  # the calibrated parameter
    valid = np.load(case["arrays"]["validation"])
    assert [str(s) for s in valid["target_signals"]] == ["angle", "speed"]
    states = simulate_neural_fmu(model, valid["time_s"], valid["u"], valid["x_init"][0])
    assert states.shape == valid["x_init"].shape and np.all(np.isfinite(states))
    assert np.abs(states[:, 2] - valid["targets"][:, 0]).max() < 5.0
    assert {"angle_mae", "speed_rmse", "objective"} <= set(best["validation"])
    with pytest.raises(ValueError, match="step"):
        simulate_neural_fmu(model, valid["time_s"] * 2, valid["u"], valid["x_init"][0])


def test_resumed_trial_equals_one_run(case, tmp_path):
    """Rung 0 then rung 1 (two jobs) ends exactly where one job straight to rung 1's resource ends."""
    plan = read_json(case["plan"])
    straight = json.loads(json.dumps(plan))
    straight["brackets"][0]["rungs"][0]["resource_s"] = plan["brackets"][0]["rungs"][1]["resource_s"]
    straight_plan = tmp_path / "straight.json"
    straight_plan.write_text(json.dumps(straight))
    config = 2
    train(case, 1, 0, config)
    two_jobs = train(case, 1, 1, config)
    folder = tmp_path / "straight"
    one_job = run_trial_rung(
        plan_path=straight_plan, bracket=1, rung=0, config_index=config,
        train_arrays_path=case["arrays"]["train"], validation_arrays_path=case["arrays"]["validation"],
        statistics_path=case["statistics"], fmu_path=case["fmu"], calibration_path=case["calibration"], roles=ROLES, model_config=case["model"],
        training_config=case["training"], previous_checkpoint=None, checkpoint_path=folder / "checkpoint.pt",
        result_path=folder / "result.json", track=False)
    a, b = load_checkpoint(two_jobs["checkpoint"]), load_checkpoint(one_job["checkpoint"])
    assert a["trainer"]["history"] == b["trainer"]["history"]
    for name, value in a["trainer"]["model"].items():
        assert torch.equal(value, b["trainer"]["model"][name]), name
    last_a, last_b = dict(a["validations"][-1]), dict(b["validations"][-1])
    last_a.pop("rung"), last_b.pop("rung")
    assert last_a == last_b
    assert math.isfinite(one_job["objective"])


def test_gradient_free_rollout_matches_the_recorded_one(case):
    """Validation and inference run the FMU in NumPy without a graph; training records for the adjoint.
    Both integrate the same model to round-off."""
    from hybridfmu.fmu import FmuRhs
    from hybridfmu.training.build import build_neural_fmu, model_spec
    from hybridfmu.training.solver import rollout

    fmu_model = load_fmu(case["fmu"])
    spec = model_spec(case["model"], fmu_model, H, width=8, depth=3, gate_opening=0.3)
    statistics = read_json(case["statistics"])
    model = build_neural_fmu(FmuRhs(fmu_model), spec, statistics, seed=4)
    with torch.no_grad():
        model.ann.output.weight.normal_(0.0, 0.3)  # a non-trivial correction
        model.delay.raw.fill_(0.4)
    arrays = np.load(case["arrays"]["validation"])
    u = torch.from_numpy(arrays["u"][None, 100:900]).repeat(2, 1, 1)
    x0 = torch.from_numpy(arrays["x_init"][[110, 110]])
    with torch.no_grad():
        fast = rollout(model, u, 10, x0, 700)
    recorded = rollout(model, u.clone().requires_grad_(True), 10, x0, 700)
    assert torch.allclose(fast, recorded.detach(), rtol=1e-10, atol=1e-9)


def test_gradient_free_rollout_through_the_derivatives_kernel_is_exact(case):
    """The validation's NumPy integration calls the bridge's ``derivatives_kernel`` (buffers reused); it gives
    the same states to the bit as plain ``derivatives`` calls, and the kernel's errors are the bridge's."""
    from hybridfmu.fmu import FmuRhs
    from hybridfmu.training.build import build_neural_fmu, model_spec
    from hybridfmu.training.solver import rollout

    fmu_model = load_fmu(case["fmu"])
    spec = model_spec(case["model"], fmu_model, H, width=8, depth=3, gate_opening=0.3)
    model = build_neural_fmu(FmuRhs(fmu_model), spec, read_json(case["statistics"]), seed=4)
    with torch.no_grad():
        model.ann.output.weight.normal_(0.0, 0.3)
    arrays = np.load(case["arrays"]["validation"])
    u = torch.from_numpy(arrays["u"][None, 100:900]).repeat(3, 1, 1)
    x0 = torch.from_numpy(arrays["x_init"][[110, 150, 190]])
    fmu_model.neural_rollout = None  # the instance's own attribute: not the loop in C, the NumPy one
    try:
        with torch.no_grad():
            fast = rollout(model, u, 10, x0, 700)
        plain = fmu_model.derivatives
        fmu_model.derivatives_kernel = lambda n: plain  # no kernel, plain calls
        try:
            with torch.no_grad():
                reference = rollout(model, u, 10, x0, 700)
        finally:
            del fmu_model.derivatives_kernel
    finally:
        del fmu_model.neural_rollout
    assert torch.equal(fast, reference)
    kernel = fmu_model.derivatives_kernel(2)
    x = arrays["x_init"][[110, 150]].copy()
    assert np.array_equal(kernel(x, arrays["u"][[110, 150]]), plain(x, arrays["u"][[110, 150]]))
    x[1, 0] = np.nan
    with pytest.raises(ValueError, match="non-finite value"):
        kernel(x, arrays["u"][[110, 150]])


@pytest.mark.parametrize("solver", ["rk4", "euler"])
def test_gradient_free_rollout_in_c_matches_the_numpy_one(case, solver):
    """Validation and inference run the neural FMU's whole loop in C (the bridge's ``neural_rollout``): the same
    states as the NumPy loop to round-off, end stop included, and NaN rows once a state is not finite."""
    from hybridfmu.fmu import FmuRhs
    from hybridfmu.training.build import build_neural_fmu, model_spec
    from hybridfmu.training.solver import rollout

    fmu_model = load_fmu(case["fmu"], parameters={"theta_min": 4.9})
    spec = model_spec(dict(case["model"], solver=solver), fmu_model, H, width=8, depth=3, gate_opening=0.3)
    model = build_neural_fmu(FmuRhs(fmu_model), spec, read_json(case["statistics"]), seed=5)
    with torch.no_grad():
        model.ann.output.weight.normal_(0.0, 0.3)
        model.delay.raw.fill_(0.3)
    arrays = np.load(case["arrays"]["validation"])
    u = torch.from_numpy(arrays["u"][None, 100:900]).repeat(3, 1, 1)
    x0 = torch.from_numpy(arrays["x_init"][[110, 150, 190]]).clone()
    x0[0, 2:] = torch.tensor([4.95, -40.0], dtype=torch.float64)  # runs into the retract stop at 4.9 rad

    def both():
        with torch.no_grad():
            in_c = rollout(model, u, 10, x0, 700)
        fmu_model.neural_rollout = None
        try:
            with torch.no_grad():
                in_numpy = rollout(model, u, 10, x0, 700)
        finally:
            del fmu_model.neural_rollout
        return in_c, in_numpy

    in_c, in_numpy = both()
    assert torch.isfinite(in_c).all()
    assert (in_c[0, :, 2] == 4.9).any(), "the end stop must be reached in this test"
    assert torch.allclose(in_c, in_numpy, rtol=1e-10, atol=1e-9)
    with torch.no_grad():  # segments of different lengths: each row integrated over its own steps, then held
        short = rollout(model, u, 10, x0, 700, row_steps=torch.tensor([700, 300, 0]))
    assert torch.equal(short[0], in_c[0]) and torch.equal(short[1, :301], in_c[1, :301])
    assert (short[1, 301:] == in_c[1, 300]).all() and (short[2] == x0[2]).all()
    with pytest.raises(ValueError, match="row_steps"):
        with torch.no_grad():
            rollout(model, u, 10, x0, 700, row_steps=torch.tensor([701, 0, 0]))
    if solver != "euler":
        return
    with torch.no_grad():
        model.ann.output.bias.fill_(math.inf)  # the first step leaves the finite numbers
    in_c, in_numpy = both()
    assert torch.equal(in_c[:, 0], x0) and torch.isnan(in_c[:, 1:]).all()
    assert torch.equal(torch.isnan(in_c), torch.isnan(in_numpy))


@pytest.mark.parametrize("solver", ["rk4", "euler"])
@pytest.mark.parametrize("jacobian_method", ["directional", "fd"])
def test_training_gradients_in_c_and_numpy_equal_the_torch_stages(case, solver, jacobian_method):
    """Training on an FMU runs the adjoint in C (``fmu.neural``; "adjoint" picks it) or with its stages in NumPy
    (``training.numpy_adjoint``): the same states and gradients as its torch stages, for every parameter (delay
    included) and the initial states, through the end stop, with the FMU's directional derivatives or finite
    differences."""
    from hybridfmu.fmu import FmuRhs
    from hybridfmu.training.build import build_neural_fmu, model_spec
    from hybridfmu.training.solver import rollout

    fmu_model = load_fmu(case["fmu"], parameters={"theta_min": 4.9})
    fmu_model.jacobian_method = jacobian_method
    spec = model_spec(dict(case["model"], solver=solver), fmu_model, H, width=8, depth=3, gate_opening=0.3)
    model = build_neural_fmu(FmuRhs(fmu_model), spec, read_json(case["statistics"]), seed=6)
    with torch.no_grad():
        model.ann.output.weight.normal_(0.0, 0.3)
        model.delay.raw.fill_(0.4)
    arrays = np.load(case["arrays"]["train"])
    u = torch.from_numpy(arrays["u"][None, 100:400]).repeat(2, 1, 1)
    results = {}
    for gradients in ("adjoint", "adjoint_c", "adjoint_numpy", "adjoint_torch"):
        model.zero_grad(set_to_none=True)
        x0 = torch.from_numpy(arrays["x_init"][[110, 130]]).clone()
        x0[1, 2:] = torch.tensor([4.95, -40.0], dtype=torch.float64)  # runs into the retract stop at 4.9 rad
        x0.requires_grad_(True)
        states = rollout(model, u, 10, x0, 250, gradients=gradients)
        (states[:, 1:, 2].abs().mean() + 1e-2 * states[:, 1:, 3].pow(2).mean()).backward()
        results[gradients] = (states.detach(), {n: p.grad.clone() for n, p in model.named_parameters()}, x0.grad)
    states_t, grads_t, x0_t = results["adjoint_torch"]
    assert (states_t[1, :, 2] == 4.9).any(), "the end stop must be reached in this test"
    assert torch.equal(results["adjoint"][0], results["adjoint_c"][0])
    for engine in ("adjoint_c", "adjoint_numpy"):
        states_e, grads_e, x0_e = results[engine]
        assert torch.allclose(states_e, states_t, rtol=1e-12, atol=1e-10), engine
        for name, grad in grads_t.items():
            assert grad.abs().sum() > 0, f"no gradient reaches {name}"
            assert torch.allclose(grads_e[name], grad, rtol=1e-8, atol=1e-11 * grad.abs().max()), (engine, name)
        assert torch.allclose(x0_e, x0_t, rtol=1e-8, atol=1e-11 * x0_t.abs().max()), engine


def test_training_rollout_in_c_stops_on_a_non_finite_state(case):
    """A training window whose state leaves the finite numbers raises FloatingPointError (the trainer skips the
    step), in C as with the torch stages."""
    from hybridfmu.fmu import FmuRhs
    from hybridfmu.training.build import build_neural_fmu, model_spec
    from hybridfmu.training.solver import rollout

    fmu_model = load_fmu(case["fmu"])
    spec = model_spec(dict(case["model"], solver="euler"), fmu_model, H, width=8, depth=2, gate_opening=0.3)
    model = build_neural_fmu(FmuRhs(fmu_model), spec, read_json(case["statistics"]), seed=7)
    with torch.no_grad():
        model.ann.output.bias.fill_(math.inf)
    arrays = np.load(case["arrays"]["train"])
    u = torch.from_numpy(arrays["u"][None, 100:200]).repeat(2, 1, 1)
    x0 = torch.from_numpy(arrays["x_init"][[110, 130]])
    for gradients in ("adjoint_c", "adjoint_torch"):
        with pytest.raises(FloatingPointError, match="non-finite state after step 1 of 50"):
            rollout(model, u, 10, x0, 50, gradients=gradients)


def test_intermediate_validations_report_the_best_state(case, tmp_path):
    training = dict(case["training"], validation_every_s=0.004)
    result = run_trial_rung(
        plan_path=case["plan"], bracket=0, rung=0, config_index=1,
        train_arrays_path=case["arrays"]["train"], validation_arrays_path=case["arrays"]["validation"],
        statistics_path=case["statistics"], fmu_path=case["fmu"], calibration_path=case["calibration"], roles=ROLES, model_config=case["model"],
        training_config=training, previous_checkpoint=None, checkpoint_path=tmp_path / "checkpoint.pt",
        result_path=tmp_path / "result.json", track=False)
    objectives = [v["objective"] for v in result["validations"]]
    assert len(objectives) >= 3 and result["objective"] == min(objectives)
    checkpoint = load_checkpoint(tmp_path / "checkpoint.pt")
    assert checkpoint["best"]["objective"] == min(objectives)
    assert checkpoint["best"]["resource_s"] <= checkpoint["trainer"]["used_samples"] * H + 1e-12


# --- faults: damaged or foreign checkpoints, a tracking store lost during the search ----------------

def test_corrupt_checkpoint_names_the_file(case, tmp_path):
    path = tmp_path / "checkpoint.pt"
    path.write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="expected a trial checkpoint") as raised:
        load_checkpoint(path)
    assert str(path) in str(raised.value)
    best = tmp_path / "best.json"
    best.write_text(json.dumps({"checkpoint": str(path)}))
    with pytest.raises(ValueError, match=str(path)):
        load_trained_neural_fmu(best, case["fmu"])


def test_checkpoint_of_another_configuration_is_refused(case, tmp_path):
    result = train(case, 0, 0, 0)
    with pytest.raises(ValueError) as raised:
        run_trial_rung(
            plan_path=case["plan"], bracket=1, rung=1, config_index=2,
            train_arrays_path=case["arrays"]["train"], validation_arrays_path=case["arrays"]["validation"],
            statistics_path=case["statistics"], fmu_path=case["fmu"], calibration_path=case["calibration"],
            roles=ROLES, model_config=case["model"], training_config=case["training"],
            previous_checkpoint=result["checkpoint"], checkpoint_path=tmp_path / "checkpoint.pt",
            result_path=tmp_path / "result.json", track=False)
    message = str(raised.value)
    assert result["checkpoint"] in message and "expected b1 r0 c2" in message and "'config'" in message
    assert not (tmp_path / "checkpoint.pt").exists() and not (tmp_path / "result.json").exists()


def test_tracking_store_lost_mid_search_keeps_the_rung_and_logs_it_later(case, tmp_path):
    """The store vanishes: the job still writes its checkpoint and result (tracking deferred, queued); the
    next job that reaches the store logs it; logging again adds no rows."""
    from mlflow.tracking import MlflowClient

    from hybridfmu.tracking import default_tracking_uri
    from hybridfmu.training.search_tracking import pending_folder, start_search, sync_pending

    plan = read_json(case["plan"])
    uri = default_tracking_uri(tmp_path / "store")
    plan["tracking"] = start_search(uri, "synthetic", plan["search_id"], "synthetic", {"R": plan["R"]})
    plan_path = tmp_path / "hpo" / "plan.json"
    write_json_atomic(plan_path, plan)
    database = tmp_path / "store" / "mlflow.db"
    database.rename(tmp_path / "away.db")  # the store is lost

    def run(rung, config):
        folder = tmp_path / "hpo" / f"b1/r{rung}/c{config}"
        previous = tmp_path / "hpo" / f"b1/r{rung - 1}/c{config}/checkpoint.pt" if rung else None
        return run_trial_rung(
            plan_path=plan_path, bracket=1, rung=rung, config_index=config,
            train_arrays_path=case["arrays"]["train"], validation_arrays_path=case["arrays"]["validation"],
            statistics_path=case["statistics"], fmu_path=case["fmu"], calibration_path=case["calibration"],
            roles=ROLES, model_config=case["model"], training_config=case["training"], previous_checkpoint=previous,
            checkpoint_path=folder / "checkpoint.pt", result_path=folder / "result.json",
            tracking_options={"retry_budget_s": 1.0})

    lost = run(0, 1)
    assert lost["status"] == "ok" and lost["tracking"]["status"] == "deferred" and lost["mlflow_run_id"] is None
    assert "mlflow.db" in lost["tracking"]["error"] and not database.exists()
    assert read_json(tmp_path / "hpo/b1/r0/c1/result.json")["tracking"]["status"] == "deferred"
    assert load_checkpoint(tmp_path / "hpo/b1/r0/c1/checkpoint.pt")["rung"] == 0
    assert [p.name for p in pending_folder(plan_path).iterdir()] == ["b1_r0_c1.json"]

    (tmp_path / "away.db").rename(database)  # the store is back: the next job logs itself and the queue
    resumed = run(1, 1)
    assert resumed["tracking"] == {"status": "logged", "error": ""} and resumed["mlflow_run_id"]
    assert not list(pending_folder(plan_path).iterdir())
    client = MlflowClient(uri)
    run_id = resumed["mlflow_run_id"]
    history = load_checkpoint(tmp_path / "hpo/b1/r1/c1/checkpoint.pt")["trainer"]["history"]
    steps = [m.step for m in client.get_metric_history(run_id, "train_loss")]
    assert len(steps) == len(set(steps)) == len({int(round(1000 * r)) for r, loss, *_ in history if math.isfinite(loss)})
    assert sorted(m.step for m in client.get_metric_history(run_id, "best_val_objective")) == sorted(
        {int(round(1000 * lost["resource_s"])), int(round(1000 * resumed["resource_s"]))})
    assert client.get_run(run_id).info.status == "FINISHED"

    from hybridfmu.training.search_tracking import record_pending
    record_pending(plan_path, lost, tmp_path / "hpo/b1/r0/c1/result.json", "again")
    assert set(sync_pending(plan_path)) == {"b1c1"}  # logging it a second time adds no rows
    assert [m.step for m in client.get_metric_history(run_id, "train_loss")] == steps


def test_rungs_queued_until_the_search_ends_are_logged_as_each_job_logs_them(case, tmp_path):
    """mlflow.rung_logging at_search_end: the jobs log nothing (their rungs wait beside the plan, status
    queued); the search's catch-up then logs the same runs, metrics and artifacts as jobs logging their own."""
    from mlflow.tracking import MlflowClient

    from hybridfmu.tracking import default_tracking_uri
    from hybridfmu.training.search_tracking import catch_up_search, pending_folder, start_search

    histories = {}
    for mode in ("each_job", "at_search_end"):
        plan = read_json(case["plan"])
        uri = default_tracking_uri(tmp_path / mode / "store")
        plan["tracking"] = start_search(uri, "synthetic", plan["search_id"], "synthetic", {"R": plan["R"]})
        plan_path = tmp_path / mode / "hpo" / "plan.json"
        write_json_atomic(plan_path, plan)
        for rung in (0, 1):
            folder = plan_path.parent / f"b1/r{rung}/c1"
            result = run_trial_rung(
                plan_path=plan_path, bracket=1, rung=rung, config_index=1,
                train_arrays_path=case["arrays"]["train"], validation_arrays_path=case["arrays"]["validation"],
                statistics_path=case["statistics"], fmu_path=case["fmu"], calibration_path=case["calibration"],
                roles=ROLES, model_config=case["model"], training_config=case["training"],
                previous_checkpoint=plan_path.parent / "b1/r0/c1/checkpoint.pt" if rung else None,
                checkpoint_path=folder / "checkpoint.pt", result_path=folder / "result.json", rung_logging=mode)
            assert read_json(folder / "result.json")["tracking"]["status"] == (
                "logged" if mode == "each_job" else "queued")
        client = MlflowClient(uri)
        children = client.search_runs([plan["tracking"]["experiment_id"]],
                                      filter_string="tags.`hybridfmu.trial` = 'b1c1'")
        if mode == "at_search_end":
            assert children == [] and result["mlflow_run_id"] is None
            assert sorted(p.name for p in pending_folder(plan_path).iterdir()) == ["b1_r0_c1.json", "b1_r1_c1.json"]
            assert catch_up_search(plan_path)
            assert not list(pending_folder(plan_path).iterdir())
            children = client.search_runs([plan["tracking"]["experiment_id"]],
                                          filter_string="tags.`hybridfmu.trial` = 'b1c1'")
        assert len(children) == 1
        run = children[0]
        histories[mode] = ({key: sorted((m.step, m.value) for m in client.get_metric_history(run.info.run_id, key))
                            for key in run.data.metrics},
                           sorted(a.path for a in client.list_artifacts(run.info.run_id)), run.info.status)
    assert histories["at_search_end"] == histories["each_job"]
    assert histories["each_job"][0]["train_loss"] and histories["each_job"][2] == "FINISHED"
    with pytest.raises(ValueError, match="rung_logging"):
        run_trial_rung(
            plan_path=case["plan"], bracket=1, rung=0, config_index=1,
            train_arrays_path=case["arrays"]["train"], validation_arrays_path=case["arrays"]["validation"],
            statistics_path=case["statistics"], fmu_path=case["fmu"], calibration_path=case["calibration"],
            roles=ROLES, model_config=case["model"], training_config=case["training"], previous_checkpoint=None,
            checkpoint_path=tmp_path / "c.pt", result_path=tmp_path / "r.json", rung_logging="later")


def test_delays_start_at_the_time_offset_estimates(case, tmp_path):
    """init_s: time_offset puts each group's estimate into the plan (and its search id); the trained model
    starts from them."""
    from hybridfmu.fmu import FmuRhs
    from hybridfmu.model import NeuralFmu
    from hybridfmu.training.build import model_spec
    from hybridfmu.training.hpo import initial_delays_from_time_offset

    model = dict(case["model"], input_delay=dict(case["model"]["input_delay"], init_s="time_offset", groups={
        "duties": ["d_a", "d_b", "d_c"], "rest": ["u_dc", "tau_load"]}))
    offset = tmp_path / "time_offset.json"
    offset.write_text(json.dumps({"groups": {"duties": {"delay_s": 2.5e-5}, "rest": {"delay_s": -1e-5}}}))
    assert initial_delays_from_time_offset(model, offset) == {"duties": 2.5e-5, "rest": -1e-5}
    assert initial_delays_from_time_offset(case["model"], offset) is None  # a number in the config is kept
    plan_path = tmp_path / "hpo" / "plan.json"
    hpo = read_json(case["plan"])
    plan = plan_search(case="synthetic", seed=11, hpo_config=case["hpo"],
        training_config=case["training"], model_config=model, plan_path=plan_path, tracking_uri=None,
        experiment=None, roles=ROLES, time_offset_path=offset)
    assert plan["initial_delays_s"] == {"duties": 2.5e-5, "rest": -1e-5}
    assert plan["search_id"] != hpo["search_id"]
    fmu_model = load_fmu(case["fmu"])
    spec = model_spec(model, fmu_model, H, width=8, depth=2, gate_opening=0.3,
                      delay_init_s=plan["initial_delays_s"])
    assert NeuralFmu(FmuRhs(fmu_model), spec, None).delay_s() == pytest.approx({"duties": 2.5e-5, "rest": -1e-5})
    with pytest.raises(ValueError, match="no estimate was given"):
        model_spec(model, fmu_model, H, width=8, depth=2, gate_opening=0.3)
    offset.write_text(json.dumps({"groups": {"inputs": {"delay_s": 0.0}}}))
    with pytest.raises(ValueError, match=r"time_offset\.json: field 'groups' estimates \['inputs'\]"):
        initial_delays_from_time_offset(model, offset)


def test_delays_learn_within_standard_errors_of_the_time_offset_estimates(case, tmp_path):
    """within_standard_errors: k bounds each identified group's delay to its estimate +- k standard errors
    (within [min_s, max_s]); a group the stage did not identify keeps the whole range."""
    from hybridfmu.fmu import FmuRhs
    from hybridfmu.model import NeuralFmu
    from hybridfmu.training.build import model_spec
    from hybridfmu.training.hpo import delay_bounds_from_time_offset

    delay = dict(case["model"]["input_delay"], init_s="time_offset", within_standard_errors=3.0, min_s=-3e-4,
                 max_s=3e-4, groups={"duties": ["d_a", "d_b", "d_c"], "rest": ["u_dc", "tau_load"]})
    model = dict(case["model"], input_delay=delay)
    offset = tmp_path / "time_offset.json"
    offset.write_text(json.dumps({"groups": {
        "duties": {"delay_s": 2.5e-5, "identified": True, "standard_error_s": 1e-6},
        "rest": {"delay_s": 0.0, "identified": False, "standard_error_s": None}}}))
    bounds = delay_bounds_from_time_offset(model, offset)
    assert bounds == {"duties": pytest.approx([2.2e-5, 2.8e-5], abs=1e-15)}
    plan = plan_search(case="synthetic", seed=11, hpo_config=case["hpo"], training_config=case["training"],
                       model_config=model, plan_path=tmp_path / "plan.json", tracking_uri=None, experiment=None,
                       roles=ROLES, time_offset_path=offset)
    assert plan["delay_bounds_s"] == bounds
    unbounded = plan_search(case="synthetic", seed=11, hpo_config=case["hpo"], training_config=case["training"],
                            model_config=dict(model, input_delay=dict(delay, within_standard_errors=None)),
                            plan_path=tmp_path / "plan2.json", tracking_uri=None, experiment=None, roles=ROLES,
                            time_offset_path=offset)
    assert "delay_bounds_s" not in unbounded and unbounded["search_id"] != plan["search_id"]
    fmu_model = load_fmu(case["fmu"])
    spec = model_spec(model, fmu_model, H, width=8, depth=2, gate_opening=0.3,
                      delay_init_s=plan["initial_delays_s"], delay_bounds_s=plan["delay_bounds_s"])
    net = NeuralFmu(FmuRhs(fmu_model), spec, None)
    with torch.no_grad():
        net.delay.raw.fill_(1e9)
    assert net.delay_s() == pytest.approx({"duties": 2.8e-5, "rest": 3e-4}, rel=1e-9)
    # an identified group without its standard error, and bounds without the time-offset start, are named
    offset.write_text(json.dumps({"groups": {"duties": {"delay_s": 2.5e-5, "identified": True},
                                             "rest": {"delay_s": 0.0, "identified": False}}}))
    with pytest.raises(ValueError, match=r"time_offset\.json: group 'duties' is identified but has no positive "
                                         r"'standard_error_s'"):
        delay_bounds_from_time_offset(model, offset)
    with pytest.raises(ValueError, match=r"within_standard_errors is 3\.0, which needs init_s: time_offset"):
        delay_bounds_from_time_offset(dict(model, input_delay=dict(delay, init_s=0.0)), offset)
