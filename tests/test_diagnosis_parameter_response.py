"""A parameter error's first-order coefficient read through the model's own response to finite errors: exact for a
derivative proportional to 1 / p, the identity for one linear in p, shared by the equations of a joint fit."""

from __future__ import annotations

import numpy as np
import pytest

from diagnosis_models import MassSpringDamper, msd_maneuvers, msd_problem
from hybridfmu.diagnosis.effects import RESPONSE_FACTORS, ParameterResponse, parameter_response, parameter_sensitivity
from hybridfmu.diagnosis.library import ResponseMap, build_library, share_response_map
from hybridfmu.diagnosis.prepare import prepare_maneuver
from hybridfmu.diagnosis.problem import set_data_statistics


def rows(n=200, seed=5):
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.normal(0, 0.5, n), rng.normal(0, 2.0, n)]), rng.normal(0, 3.0, (n, 1))


def test_the_response_of_a_derivative_proportional_to_one_over_p_is_r_over_one_plus_r():
    model = MassSpringDamper()
    x, u = rows()
    response = parameter_response(model, x, u, "m", parameter_sensitivity(model, x, u, "m"))
    r = RESPONSE_FACTORS - 1.0
    np.testing.assert_allclose(response.relative, r)
    np.testing.assert_allclose(response.coefficients(np.array([0.0, 1.0])), r / (1.0 + r), rtol=1e-6, atol=1e-9)
    assert model.values["m"] == 1.0  # restored
    damping = parameter_response(model, x, u, "c", parameter_sensitivity(model, x, u, "c"))
    np.testing.assert_allclose(damping.coefficients(np.array([0.0, 1.0])), r, rtol=1e-6, atol=1e-9)
    # dx/dt = v has no sensitivity to m: no coefficient there
    assert np.all(np.isnan(response.coefficients(np.array([1.0, 0.0]))))


def test_values_the_model_rejects_are_left_out_and_a_zero_parameter_has_no_relative_response():
    class Bounded(MassSpringDamper):
        def set_parameters(self, values):
            if values.get("m", 1.0) > 2.0:
                raise ValueError("m above 2")
            super().set_parameters(values)

    model = Bounded()
    x, u = rows()
    response = parameter_response(model, x, u, "m", parameter_sensitivity(model, x, u, "m"))
    assert response.relative.max() <= 1.0 and response.relative.min() == pytest.approx(-0.75)
    assert model.values["m"] == 1.0
    zero = MassSpringDamper(c=0.0)
    assert parameter_response(zero, x, u, "c", parameter_sensitivity(zero, x, u, "c")) is None


def test_the_map_inverts_the_response_and_continues_it_beyond_its_ends():
    r = RESPONSE_FACTORS - 1.0
    inverse = ResponseMap(r, r / (1.0 + r))
    for truth in (-0.5, -0.17, 0.0, 0.1, 0.1746, 1.0, 2.5):
        assert inverse(truth / (1.0 + truth)) == pytest.approx(truth, rel=1e-4, abs=1e-9)
    assert inverse.slope(0.0) == pytest.approx(1.0, rel=1e-2)
    # beyond c(3) = 0.75 the map goes on with the slope at its end (dr/dc = (1 + r)^2 = 16 there)
    assert inverse(0.8) == pytest.approx(3.0 + 0.05 * 16.0, rel=1e-2)
    assert not inverse.is_identity
    for identity in (ResponseMap(), ResponseMap(r, r), ResponseMap(r[:2], r[:2])):
        assert identity(0.3) == pytest.approx(0.3) and identity.slope(0.3) == pytest.approx(1.0)


def test_a_response_that_turns_back_is_read_on_its_branch_through_zero():
    r = RESPONSE_FACTORS - 1.0
    turning = r - 0.4 * r ** 2  # rises up to r = 1.25, falls beyond
    inverse = ResponseMap(r, turning)
    assert inverse(0.5 - 0.4 * 0.25) == pytest.approx(0.5, rel=1e-3)
    assert inverse(1.25 - 0.4 * 1.25 ** 2 - 0.01) < 1.25


@pytest.fixture(scope="module")
def library():
    problem, model = msd_problem(equations=["x", "v"])
    measured = msd_maneuvers(None, duration_s=5.0)
    set_data_statistics(problem, [measured["train"].x], 0.01)
    prepared = prepare_maneuver(measured["train"], model, problem)
    effects, _ = build_library(problem, prepared.inputs, model)
    return {e.name: e for e in effects[1]}


def test_a_parameter_error_reads_its_coefficient_through_the_response(library):
    mass, damping = library["parameter(m)"], library["parameter(c)"]
    coefficient = np.array([0.1 / 1.1])  # f / 1.1 = f (1 - 0.1 / 1.1): first order in -(m df/dm) = f
    assert mass.relative_error(coefficient) == pytest.approx(0.1, rel=1e-4)
    assert mass.parameter_change(coefficient, {}) == ("m", pytest.approx(1.1, rel=1e-4))
    rows_ = {row["name"]: row for row in mass.physical(coefficient, np.array([[1e-6]]), {}, {})}
    assert rows_["relative_error"]["value"] == pytest.approx(0.1, rel=1e-4)
    assert rows_["corrected_value"]["value"] == pytest.approx(1.1, rel=1e-4)
    # the standard error goes through the map's slope, dr/dc = (1 + r)^2 = 1.21
    assert rows_["relative_error"]["se"] == pytest.approx(1e-3 * 1.21, rel=1e-2)
    assert damping.relative_error(np.array([0.1])) == pytest.approx(0.1, rel=1e-4)


def test_a_joint_fit_weights_the_equations_responses():
    relative = RESPONSE_FACTORS - 1.0
    numerator = np.column_stack([relative, relative / (1.0 + relative)])  # linear in one equation, 1 / p in the other
    response = ParameterResponse(relative, numerator, np.array([1.0, 1.0]))

    class Member:
        pass

    from hybridfmu.diagnosis.library import ParameterError

    members = []
    for equation in (0, 1):
        member = ParameterError.__new__(ParameterError)
        member.equation, member.response = equation, response
        member.response_map = ResponseMap.of(response, np.eye(2)[equation])
        members.append(member)
    assert members[0].response_map(0.2) == pytest.approx(0.2, rel=1e-4)
    assert members[1].response_map(0.2) == pytest.approx(0.25, rel=1e-4)
    share_response_map(members + [Member()], {0: 1.0, 1: 3.0})
    expected = (1.0 * 0.3 + 3.0 * 0.3 / 1.3) / 4.0  # c(0.3) of the weighted fit
    for member in members:
        assert member.response_map(expected) == pytest.approx(0.3, rel=1e-4)
