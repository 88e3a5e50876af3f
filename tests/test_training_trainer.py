"""Training: windows, losses, the trainer's resumable state, skipped steps, determinism (pure-torch motor)."""

import dataclasses
import io

import numpy as np
import pytest
import torch

from hybridfmu.model import MotorParameters, MotorRhs, NeuralFmu, NeuralFmuSpec
from hybridfmu.training.data import ManeuverArrays
from hybridfmu.training.losses import error_measures, weighted_loss
from hybridfmu.training.statistics import data_statistics
from hybridfmu.training.synthetic import motor_inputs, simulate_rhs
from hybridfmu.training.trainer import Hyperparameters, Trainer, TrainerSettings, TrialDiverged
from hybridfmu.training.validation import validate
from hybridfmu.training.windows import WindowSampler

H = 1e-4


class NumpyMotor:
    """The FMU-like batched interface (numpy) of the pure-torch motor, for the statistics."""

    state_names, input_names = MotorRhs.state_names, MotorRhs.input_names

    def derivatives(self, x, u):
        return MotorRhs()(torch.from_numpy(x), torch.from_numpy(u)).numpy()


@pytest.fixture(scope="module")
def arrays():
    n = 3000
    u = motor_inputs(n, H, seed=0, theta0_rad=5.0)
    states = simulate_rhs(MotorRhs(MotorParameters(J=2.4e-4, b=1e-4)), u, np.array([0.0, 0.0, 5.0, 0.0]), H)
    return ManeuverArrays(name="synthetic", time_s=np.arange(n) * H, u=u, x_init=states, angle=states[:, 2].copy(),
                          speed=states[:, 3].copy(), spans=np.array([[300, 1400], [1600, 2900]]),
                          state_names=MotorRhs.state_names, input_names=MotorRhs.input_names, angle_state="theta",
                          speed_state="omega", measured_states=MotorRhs.state_names)


@pytest.fixture(scope="module")
def statistics(arrays):
    return data_statistics(arrays, NumpyMotor())


def make_model(statistics, seed=0, width=8, depth=2):
    spec = NeuralFmuSpec(state_names=MotorRhs.state_names, input_names=MotorRhs.input_names,
                         corrected_states=["omega"], ann_states=MotorRhs.state_names, ann_inputs=MotorRhs.input_names,
                         ann_derivatives=MotorRhs.state_names, sample_period_s=H, width=width, depth=depth,
                         gate_opening=0.2, delay_min_s=-3e-4, delay_max_s=3e-4)
    torch.manual_seed(seed)
    return NeuralFmu(MotorRhs(), spec, statistics)


HYPER = Hyperparameters(lr=3e-3, beta1=0.9, beta2=0.999, window_s=0.004, loss="MAE", w_speed=0.7, width=8, depth=2,
                        gate_opening=0.2, batch_windows=4)


def make_trainer(arrays, statistics, seed=5, settings=TrainerSettings(), hyper=HYPER):
    return Trainer(make_model(statistics), arrays, hyper, statistics, settings, seed)


def test_windows_lie_inside_segments(arrays):
    sampler = WindowSampler(arrays, n_steps=150, pad=4)
    starts = sampler.sample_starts(np.random.default_rng(0), 2000)
    inside = ((starts >= 300) & (starts + 150 < 1400)) | ((starts >= 1600) & (starts + 150 < 2900))
    assert inside.all()
    assert starts.min() < 330 and starts.max() > 2700  # both segments, near their ends
    batch = sampler.gather(starts[:3])
    assert batch.u_seq.shape == (3, 150 + 2 * 4 + 1, 5) and batch.start_index == 4
    assert torch.equal(batch.u_seq[:, 4], torch.from_numpy(arrays.u[starts[:3]]))
    assert torch.equal(batch.angle[:, -1], torch.from_numpy(arrays.angle[starts[:3] + 150]))
    with pytest.raises(ValueError, match="no selected segment holds a window"):
        WindowSampler(arrays, n_steps=1400, pad=4)


def test_weighted_loss_and_measures():
    angle_error = torch.tensor([[0.0, 2.0, -2.0]], dtype=torch.float64)
    speed_error = torch.tensor([[0.0, 10.0, 0.0]], dtype=torch.float64)
    mae = weighted_loss(angle_error, speed_error, "MAE", 0.25, angle_scale=2.0, speed_scale=5.0)
    assert mae.item() == pytest.approx(0.75 * (2 / 3) + 0.25 * (2 / 3))
    mse = weighted_loss(angle_error, speed_error, "MSE", 1.0, angle_scale=2.0, speed_scale=5.0)
    assert mse.item() == pytest.approx(4 / 3)
    masked = weighted_loss(angle_error, speed_error, "MAE", 0.0, 1.0, 1.0, mask=torch.tensor([[False, True, False]]))
    assert masked.item() == 2.0
    assert error_measures(angle_error, speed_error) == pytest.approx(
        {"angle_mae": 4 / 3, "angle_mse": 8 / 3, "speed_mae": 10 / 3, "speed_mse": 100 / 3})
    with pytest.raises(ValueError, match="loss kind"):
        weighted_loss(angle_error, speed_error, "L1", 0.5, 1.0, 1.0)


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
    assert a.model.delay_s() != 0.0  # dt is trained
    objective = {"loss": "MAE", "w_speed": 0.5}
    short = dataclasses.replace(arrays, spans=np.array([[300, 700], [1600, 2000]]))
    trained = validate(a.model, short, "MAE", 0.7, objective, statistics)
    untrained = validate(make_model(statistics), short, "MAE", 0.7, objective, statistics)
    assert trained["finite"] == 1.0 and trained["objective"] < untrained["objective"]


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
