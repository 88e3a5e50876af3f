"""Training: windows, losses, the trainer's resumable state, skipped steps, determinism (pure-torch pendulum)."""

import dataclasses
import io

import numpy as np
import pytest
import torch

from hybridfmu.model import NeuralFmu, NeuralFmuSpec
from hybridfmu.training.data import ManeuverArrays
from hybridfmu.training.losses import Objective, error_measures, weighted_loss
from hybridfmu.training.statistics import data_statistics
from hybridfmu.training.trainer import Hyperparameters, Trainer, TrainerSettings, TrialDiverged
from hybridfmu.training.validation import validate
from hybridfmu.training.windows import WindowSampler
from test_model_layers import Pendulum

H = 1e-4
TARGETS, SIGNALS = ["p", "v"], ["position", "rate"]
WEIGHTS = {"p": 0.3, "v": 0.7}


class TruePendulum(Pendulum):
    """The "real" system: stiffer and more damped than the model."""

    K, C = 460.0, 3.0


class NumpyPendulum:
    """The FMU-like batched interface (numpy) of the pure-torch model, for the statistics."""

    state_names, input_names = Pendulum.state_names, Pendulum.input_names

    def derivatives(self, x, u):
        return Pendulum()(torch.from_numpy(x), torch.from_numpy(u)).numpy()


def pendulum_inputs(n: int, seed: int) -> np.ndarray:
    """(n, 2) drive (rad/s^2) and damping gain: slow sines plus a little noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * H
    drive = 150.0 * np.sin(2 * np.pi * 7.0 * t) + 60.0 * np.sin(2 * np.pi * 23.0 * t) + rng.normal(0, 2.0, n)
    gain = 1.0 + 0.3 * np.sin(2 * np.pi * 3.0 * t)
    return np.column_stack([drive, gain])


def simulate(rhs, u: np.ndarray, x0: np.ndarray) -> np.ndarray:
    """RK4 with inputs held per sample: u (T, 2), x0 (3,) -> states (T, 3)."""
    u_t = torch.from_numpy(u)
    x = torch.from_numpy(x0)[None]
    states = [x]
    for k in range(u.shape[0] - 1):
        uk = u_t[k:k + 1]
        k1 = rhs(x, uk)
        k2 = rhs(x + 0.5 * H * k1, uk)
        k3 = rhs(x + 0.5 * H * k2, uk)
        k4 = rhs(x + H * k3, uk)
        x = x + H / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        states.append(x)
    return torch.cat(states).numpy()


@pytest.fixture(scope="module")
def arrays():
    n = 3000
    u = pendulum_inputs(n, seed=0)
    states = simulate(TruePendulum(), u, np.array([0.2, 0.0, 0.0]))
    return ManeuverArrays(name="synthetic", time_s=np.arange(n) * H, u=u, x_init=states, targets=states[:, :2].copy(),
                          spans=np.array([[300, 1400], [1600, 2900]]), state_names=Pendulum.state_names,
                          input_names=Pendulum.input_names, target_states=TARGETS, target_signals=SIGNALS,
                          measured_states=Pendulum.state_names)


@pytest.fixture(scope="module")
def statistics(arrays):
    return data_statistics(arrays, NumpyPendulum())


def make_model(statistics, seed=0, width=8, depth=2):
    spec = NeuralFmuSpec(state_names=Pendulum.state_names, input_names=Pendulum.input_names,
                         corrected_states=["v"], ann_states=Pendulum.state_names, ann_inputs=Pendulum.input_names,
                         ann_derivatives=Pendulum.state_names, sample_period_s=H, width=width, depth=depth,
                         gate_opening=0.2, delay_min_s=-3e-4, delay_max_s=3e-4)
    torch.manual_seed(seed)
    return NeuralFmu(Pendulum(), spec, statistics)


HYPER = Hyperparameters(lr=3e-3, beta1=0.9, beta2=0.999, window_s=0.004, loss="MAE", width=8, depth=2,
                        gate_opening=0.2, batch_windows=4, target_weights={"v": 0.7})


def make_trainer(arrays, statistics, seed=5, settings=TrainerSettings(), hyper=HYPER):
    return Trainer(make_model(statistics), arrays, hyper, statistics, settings, seed, WEIGHTS)


def test_windows_lie_inside_segments(arrays):
    sampler = WindowSampler(arrays, n_steps=150, pad=4)
    starts = sampler.sample_starts(np.random.default_rng(0), 2000)
    inside = ((starts >= 300) & (starts + 150 < 1400)) | ((starts >= 1600) & (starts + 150 < 2900))
    assert inside.all()
    assert starts.min() < 330 and starts.max() > 2700  # both segments, near their ends
    batch = sampler.gather(starts[:3])
    assert batch.u_seq.shape == (3, 150 + 2 * 4 + 1, 2) and batch.start_index == 4
    assert torch.equal(batch.u_seq[:, 4], torch.from_numpy(arrays.u[starts[:3]]))
    assert batch.targets.shape == (3, 151, 2)
    assert torch.equal(batch.targets[:, -1], torch.from_numpy(arrays.targets[starts[:3] + 150]))
    with pytest.raises(ValueError, match="no selected segment holds a window"):
        WindowSampler(arrays, n_steps=1400, pad=4)


def test_weighted_loss_and_measures():
    errors = torch.tensor([[[0.0, 0.0], [2.0, 10.0], [-2.0, 0.0]]], dtype=torch.float64)  # (1, 3 samples, 2 targets)
    mae = weighted_loss(errors, "MAE", [0.75, 0.25], [2.0, 5.0])
    assert mae.item() == pytest.approx(0.75 * (2 / 3) + 0.25 * (2 / 3))
    mse = weighted_loss(errors, "MSE", [0.0, 1.0], [2.0, 5.0])
    assert mse.item() == pytest.approx(4 / 3)
    masked = weighted_loss(errors, "MAE", [1.0, 0.0], [1.0, 1.0], mask=torch.tensor([[False, True, False]]))
    assert masked.item() == 2.0
    three = torch.cat([errors, errors[..., :1]], dim=-1)
    assert weighted_loss(three, "MAE", [0.5, 0.25, 0.25], [1.0, 1.0, 2.0]).item() == pytest.approx(
        0.5 * 4 / 3 + 0.25 * 10 / 3 + 0.25 * 2 / 3)
    assert error_measures(errors, ["position", "rate"]) == pytest.approx(
        {"position_mae": 4 / 3, "position_mse": 8 / 3, "position_rmse": (8 / 3) ** 0.5,
         "rate_mae": 10 / 3, "rate_mse": 100 / 3, "rate_rmse": (100 / 3) ** 0.5})
    with pytest.raises(ValueError, match="loss kind"):
        weighted_loss(errors, "L1", [0.5, 0.5], [1.0, 1.0])
    with pytest.raises(ValueError, match="2 targets but 1 weights"):
        weighted_loss(errors, "MAE", [1.0], [1.0, 1.0])


def test_hyperparameters_carry_target_weights():
    values = {**HYPER.to_dict()}
    assert values["w_v"] == 0.7 and "target_weights" not in values
    assert Hyperparameters.from_dict(values) == HYPER
    with pytest.raises(ValueError, match="unknown"):
        Hyperparameters.from_dict({**values, "w_speedy": 0.1, "momentum": 0.5})


def test_resumed_training_equals_uninterrupted(arrays, statistics):
    whole = make_trainer(arrays, statistics)
    whole.train_until(0.12)
    first = make_trainer(arrays, statistics)
    first.train_until(0.06)
    assert 0 < first.steps < whole.steps
    buffer = io.BytesIO()
    torch.save(first.state_dict(), buffer)
    buffer.seek(0)
    resumed = make_trainer(arrays, statistics)
    resumed.load_state_dict(torch.load(buffer, weights_only=False))
    resumed.train_until(0.12)
    assert resumed.steps == whole.steps and resumed.used_samples == whole.used_samples
    assert resumed.history == whole.history
    for (name, a), b in zip(whole.model.state_dict().items(), resumed.model.state_dict().values()):
        assert torch.equal(a, b), name
    assert resumed.rng.bit_generator.state == whole.rng.bit_generator.state
    # training stops at the first step boundary at or beyond the target: 8 steps of 4 x 40 samples
    assert whole.steps == 8 and whole.resource_used_s == pytest.approx(0.128)


def test_training_is_deterministic_and_learns(arrays, statistics):
    a, b = make_trainer(arrays, statistics), make_trainer(arrays, statistics)
    a.train_until(0.32)
    b.train_until(0.32)
    assert a.history == b.history
    other = make_trainer(arrays, statistics, seed=6)
    other.train_until(0.016)
    assert other.history[0][1] != a.history[0][1]  # another seed draws other windows
    losses = [row[1] for row in a.history]
    assert np.mean(losses[-10:]) < 0.8 * np.mean(losses[:10])
    # dt is trained: from 0 it moves to 3.98e-6 s in these 0.32 s of training (bounds +-3e-4 s); a delay left
    # out of the optimiser, or without gradient, stays at exactly 0
    assert 1e-6 < abs(a.model.delay_s()["inputs"]) < 3e-4
    objective = Objective("MAE", {"p": 0.5, "v": 0.5})
    short = dataclasses.replace(arrays, spans=np.array([[300, 700], [1600, 2000]]))
    trained = validate(a.model, short, "MAE", WEIGHTS, objective, statistics)
    untrained = validate(make_model(statistics), short, "MAE", WEIGHTS, objective, statistics)
    assert trained["finite"] == 1.0 and trained["objective"] < untrained["objective"]
    assert {"position_mae", "position_mse", "position_rmse", "rate_mae", "rate_mse", "rate_rmse"} <= set(trained)
    assert trained["rate_mae"] < untrained["rate_mae"]


def test_bad_gradients_are_skipped_then_the_trial_diverges(arrays, statistics):
    trainer = make_trainer(arrays, statistics, settings=TrainerSettings(max_skipped_steps=3, max_grad_norm=1e-30))
    before = {k: v.clone() for k, v in trainer.model.state_dict().items()}
    with pytest.raises(TrialDiverged, match="4 steps skipped"):
        trainer.train_until(1.0)
    assert trainer.steps == 4 and trainer.skipped_steps == 4
    assert all(row[2] == 1.0 for row in trainer.history)
    for name, value in trainer.model.state_dict().items():
        assert torch.equal(value, before[name]), name


def test_non_finite_loss_is_skipped(arrays, statistics):
    trainer = make_trainer(arrays, statistics, settings=TrainerSettings(max_skipped_steps=1))
    with torch.no_grad():
        trainer.model.ann.output.bias.fill_(float("nan"))
    result = trainer.step()
    assert result["skipped"] == 1.0 and np.isnan(result["loss"])
    assert trainer.skipped_steps == 1


def test_adam_is_torch_adam_bit_for_bit():
    """The trainer's Adam follows torch.optim.Adam's numbers exactly and reads and writes its state dicts."""
    from hybridfmu.training.optim import Adam

    def run(make, steps=12, reload_at=None):
        torch.manual_seed(0)
        weight = torch.randn(5, 3, dtype=torch.float64, requires_grad=True)
        bias = torch.randn(3, dtype=torch.float64, requires_grad=True)
        optimizer = make([weight, bias])
        x = torch.randn(40, 5, dtype=torch.float64)
        for step in range(steps):
            optimizer.zero_grad(set_to_none=True)
            ((x @ weight + bias).tanh() ** 2).mean().backward()
            optimizer.step()
            if step == reload_at:
                state = optimizer.state_dict()
                optimizer = make([weight, bias])
                optimizer.load_state_dict(state)
        return torch.cat([weight.detach().ravel(), bias.detach().ravel()]), optimizer

    ours = lambda params: Adam(params, lr=1e-2, betas=(0.9, 0.99))  # noqa: E731
    theirs = lambda params: torch.optim.Adam(params, lr=1e-2, betas=(0.9, 0.99))  # noqa: E731
    values, optimizer = run(ours)
    reference, torch_optimizer = run(theirs)
    assert torch.equal(values, reference)
    assert torch.equal(run(ours, reload_at=5)[0], reference)
    state, torch_state = optimizer.state_dict(), torch_optimizer.state_dict()
    assert state["param_groups"] == torch_state["param_groups"]
    assert state["state"].keys() == torch_state["state"].keys()
    for index, entry in torch_state["state"].items():
        assert entry.keys() == state["state"][index].keys()
        for key, value in entry.items():
            assert value.dtype == state["state"][index][key].dtype and torch.equal(value, state["state"][index][key])
    params = [torch.zeros(5, 3, dtype=torch.float64, requires_grad=True), torch.zeros(3, dtype=torch.float64,
                                                                                        requires_grad=True)]
    theirs(params).load_state_dict(state)  # either reads the other's state
    ours(params).load_state_dict(torch_state)


def test_training_steps_do_not_import_torch_dynamo():
    """torch.optim.Optimizer imports torch._dynamo (seconds of every job's start-up); the trainer does not."""
    import subprocess
    import sys
    import textwrap

    code = textwrap.dedent("""
        import sys
        import torch
        from hybridfmu.training.optim import Adam
        weight = torch.zeros(3, requires_grad=True)
        optimizer = Adam([weight], lr=0.1, betas=(0.9, 0.999))
        (weight - 1.0).square().sum().backward()
        optimizer.step()
        optimizer.zero_grad()
        optimizer.load_state_dict(optimizer.state_dict())
        assert "torch._dynamo" not in sys.modules, "torch._dynamo was imported"
    """)
    subprocess.run([sys.executable, "-c", code], check=True)


def test_validation_batch_is_shared_without_changing_the_result(arrays, statistics):
    from hybridfmu.training.validation import validation_batch

    model = make_model(statistics)
    objective = Objective("MAE", {"p": 0.5, "v": 0.5})
    alone = validate(model, arrays, "MSE", WEIGHTS, objective, statistics)
    batch = validation_batch(model.spec, arrays)
    assert validate(model, arrays, "MSE", WEIGHTS, objective, statistics, batch) == alone
    assert validate(model, arrays, "MSE", WEIGHTS, objective, statistics, batch) == alone


def test_the_gradients_setting_chooses_how_a_step_is_differentiated(arrays, statistics):
    """``training.gradients``: the adjoint's engines and autograd train the same numbers to rounding;
    torchdiffeq's RK4 (3/8 rule) trains nearly the same; an unknown method fails the step loudly."""
    losses = {}
    for gradients in ("adjoint", "adjoint_torch", "autograd", "torchdiffeq"):
        trainer = make_trainer(arrays, statistics, settings=TrainerSettings(gradients=gradients))
        losses[gradients] = [trainer.step()["loss"] for _ in range(3)]
    assert np.allclose(losses["adjoint_torch"], losses["adjoint"], rtol=1e-10)
    assert np.allclose(losses["autograd"], losses["adjoint"], rtol=1e-10)
    assert np.allclose(losses["torchdiffeq"], losses["adjoint"], rtol=1e-3)
    trainer = make_trainer(arrays, statistics, settings=TrainerSettings(gradients="backprop"))
    with pytest.raises(ValueError, match="gradients must be"):
        trainer.step()


def test_delays_take_their_own_adam_step(arrays, statistics):
    """With step_s the delays move by about step_s per step whatever the network's lr (Adam's first step is
    lr in every coordinate); without it they move by about lr * scale_s."""
    def first_step_change(**spec_changes):
        model = make_model(statistics)
        model.spec = dataclasses.replace(model.spec, **spec_changes)
        trainer = Trainer(model, arrays, HYPER, statistics, TrainerSettings(), 5, WEIGHTS)
        before = model.delay_s()["inputs"]
        trainer.step()
        return abs(model.delay_s()["inputs"] - before), trainer

    change, trainer = first_step_change(delay_step_s=2e-6)
    assert change == pytest.approx(2e-6, rel=1e-3)
    assert [group["lr"] for group in trainer.optimizer.param_groups] == [HYPER.lr, pytest.approx(2e-6 / 1e-4)]
    change, _ = first_step_change()
    assert change == pytest.approx(HYPER.lr * 1e-4, rel=1e-3)
    # the optimizer's state with two groups has torch.optim.Adam's layout and loads into it
    model = trainer.model
    state = trainer.optimizer.state_dict()
    reference = torch.optim.Adam([{"params": [p for p in model.parameters() if p is not model.delay.raw]},
                                  {"params": [model.delay.raw], "lr": 0.02}], lr=HYPER.lr)
    reference.load_state_dict(state)
    assert [len(g["params"]) for g in reference.state_dict()["param_groups"]] == \
           [len(g["params"]) for g in state["param_groups"]]
