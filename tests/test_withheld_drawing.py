"""Drawing the withheld-effect cases: seeds, stratified log-uniform sizes relative to the demo's effects, shapes
drawn apart from the demo's, parameter offsets in every case (no FMU, no emulation)."""

from __future__ import annotations

import copy
import math
from pathlib import Path

import numpy as np
import pytest

from hybridfmu.config import read_config_file, validate_case_config
from hybridfmu_bench.withheld import suite as withheld

ROOT = Path(__file__).resolve().parents[1]
EFFECTS = ["coulomb_friction", "viscous_friction", "load_dependent_friction", "cogging", "inverter_deadtime",
           "channel_time_offset", "inertia_mismatch"]


@pytest.fixture(scope="module")
def config():
    """The demo config with a withheld section of its own (independent of the one config/config.yaml holds)."""
    raw = read_config_file(ROOT / "config" / "config.yaml")
    maneuvers = copy.deepcopy((raw.get("withheld") or {})["maneuvers"])
    raw["withheld"] = {"seeds": [0, 1, 2], "sizes_per_effect": 2, "size_range": [0.1, 3.0], "effects": [],
                       "pairs": [["cogging", "channel_time_offset"]], "none_case": True, "maneuvers": maneuvers}
    return validate_case_config(raw)


def test_every_case_exists_once_per_seed(config):
    names = withheld.case_names(config)
    per_seed = 2 * len(EFFECTS) + 1 + 1
    assert len(names) == len(set(names)) == 3 * per_seed
    assert names[0] == "s0__single_coulomb_friction__size1"
    assert "s2__pair_cogging__channel_time_offset" in names and "s1__none" in names
    for name in names:
        case = withheld.parse_case(name)
        assert case.name == name and name.startswith(f"s{case.seed}__")
    assert withheld.parse_case("s1__single_inverter_deadtime__size2").effects == ("inverter_deadtime",)
    assert withheld.parse_case("s1__single_inverter_deadtime__size2").stratum == 2
    assert withheld.parse_case("s0__pair_cogging__channel_time_offset").effects == ("cogging", "channel_time_offset")
    assert withheld.case_effects("s3__none") == []


def test_a_case_is_drawn_from_its_id_alone_so_a_larger_suite_leaves_it_unchanged(config, tmp_path):
    """Generated with only the selection that makes it exist (the rule's params), or within a suite with more seeds
    and pairs: the same case config and draw."""
    larger = copy.deepcopy(config)
    larger["withheld"]["seeds"] = [0, 1, 2, 3, 4, 5]
    larger["withheld"]["pairs"].append(["viscous_friction", "cogging"])
    for name in ("s1__single_cogging__size2", "s2__pair_cogging__channel_time_offset", "s0__none"):
        own = copy.deepcopy(config)
        own["withheld"].update(withheld.case_selection(name))
        assert withheld.case_names(own) and name in withheld.case_names(own)
        drawn = [withheld.draw_case(c, name) for c in (config, own, larger)]
        assert drawn[0] == drawn[1] == drawn[2]
        assert withheld.case_config(own, name, "m.fmu", drawn[1]) == withheld.case_config(larger, name, "m.fmu",
                                                                                          drawn[2])


def test_stratified_log_uniform_stays_in_its_stratum_and_is_log_uniform_there():
    rng = np.random.default_rng(1)
    low, high, strata = 0.1, 3.0, 3
    edges = np.geomspace(low, high, strata + 1)
    for k in range(1, strata + 1):
        values = np.array([withheld.stratified_log_uniform(rng, low, high, k, strata) for _ in range(4000)])
        assert values.min() >= edges[k - 1] and values.max() <= edges[k]
        u = (np.log(values) - math.log(edges[k - 1])) / (math.log(edges[k]) - math.log(edges[k - 1]))
        assert abs(np.median(u) - 0.5) < 0.03 and abs(np.quantile(u, 0.25) - 0.25) < 0.03
    with pytest.raises(ValueError, match="sizes_per_effect"):
        withheld.stratified_log_uniform(rng, low, high, 4, strata)


def test_every_seed_covers_the_size_range_and_draws_are_reproducible(config):
    edges = np.geomspace(0.1, 3.0, 3)
    for seed in (0, 1, 2):
        for effect in EFFECTS:
            scales = [withheld.draw_case(config, f"s{seed}__single_{effect}__size{k}")["size_scales"][effect]
                      for k in (1, 2)]
            assert edges[0] <= scales[0] <= edges[1] <= scales[1] <= edges[2]
    name = "s1__single_cogging__size2"
    assert withheld.draw_case(config, name) == withheld.draw_case(config, name)
    assert withheld.draw_case(config, name) != withheld.draw_case(config, "s2__single_cogging__size2")
    # a case's draw does not depend on which other cases the suite has
    fewer = copy.deepcopy(config)
    fewer["withheld"]["effects"] = ["cogging"]
    assert withheld.draw_case(fewer, name) == withheld.draw_case(config, name)


def test_sizes_scale_the_demo_effects_and_shapes_differ_from_them(config):
    demo = config["bench"]["effects"]
    seen_signs, orders = set(), set()
    for seed in (0, 1, 2):
        for k in (1, 2):
            draw = withheld.draw_case(config, f"s{seed}__single_coulomb_friction__size{k}")
            s, p = draw["size_scales"]["coulomb_friction"], draw["parameters"]["coulomb_friction"]
            assert p["coulomb_torque_nm"] == pytest.approx(demo["coulomb_friction"]["coulomb_torque_nm"] * s)
            assert p["breakaway_torque_nm"] == pytest.approx(demo["coulomb_friction"]["breakaway_torque_nm"] * s)
            for key in ("stribeck_speed_rad_s", "smoothing_speed_rad_s"):
                factor = p[key] / demo["coulomb_friction"][key]
                assert 0.5 <= factor <= 2.0 and factor != 1.0
                assert draw["shape_factors"]["coulomb_friction"][key] == pytest.approx(factor)
            draw = withheld.draw_case(config, f"s{seed}__single_inertia_mismatch__size{k}")
            scale = draw["parameters"]["inertia_mismatch"]["scale"]
            assert abs(scale - 1.0) == pytest.approx((demo["inertia_mismatch"]["scale"] - 1.0)
                                                     * draw["size_scales"]["inertia_mismatch"])
            draw = withheld.draw_case(config, f"s{seed}__single_channel_time_offset__size{k}")
            offset = draw["parameters"]["channel_time_offset"]["offset_s"]
            assert abs(offset) == pytest.approx(demo["channel_time_offset"]["offset_s"]
                                                * draw["size_scales"]["channel_time_offset"])
            seen_signs.add(math.copysign(1.0, offset))
            draw = withheld.draw_case(config, f"s{seed}__single_cogging__size{k}")
            harmonic, = draw["parameters"]["cogging"]["harmonics"]
            assert harmonic["amplitude_nm"] == pytest.approx(0.012 * draw["size_scales"]["cogging"])  # strongest
            assert harmonic["order_per_rev"] in (6, 12, 24, 36, 48) and harmonic["phase_rad"] != 0.0
            orders.add(harmonic["order_per_rev"])
    assert seen_signs == {-1.0, 1.0} and len(orders) > 1


def test_every_case_carries_parameter_offsets_like_the_demo_bench(config, tmp_path):
    demo = config["bench"]["true_parameter_offsets"]
    for name in withheld.case_names(config):
        offsets = withheld.draw_case(config, name)["parameter_offsets"]
        assert set(offsets) == set(demo)
        for p, value in offsets.items():
            assert 0.5 <= value / demo[p] <= 1.5
    case = withheld.case_config(config, "s0__none", tmp_path / "IPBMotor.fmu")
    assert case["bench"]["true_parameter_offsets"] == withheld.draw_case(config, "s0__none")["parameter_offsets"]
    assert case["bench"]["effects"] == {} and case["fmu"]["parameters"] == config["fmu"]["parameters"]
    assert "bench" not in withheld.without_bench(case) and "diagnosis" in withheld.without_bench(case)


def test_case_configs_withhold_exactly_the_effects(config, tmp_path):
    name = "s1__pair_cogging__channel_time_offset"
    case = withheld.case_config(config, name, tmp_path / "IPBMotor.fmu")
    assert sorted(case["bench"]["effects"]) == ["channel_time_offset", "cogging"]
    assert case["case"] == name and case["fmu"]["source"] == "path"
    assert case["maneuvers"]["test"]["role"] == "test"
    assert case["maneuvers"]["test"]["raw"] == f"{config['results_dir']}/withheld/{name}/raw/test.mf4"
    draw_path, case_path = tmp_path / "case.draw.json", tmp_path / "case.yaml"
    withheld.write_case_config(config, name, tmp_path / "IPBMotor.fmu", case_path, draw_path)
    assert withheld.load_case(case_path)["bench"]["effects"]["cogging"] == case["bench"]["effects"]["cogging"]
    assert draw_path.is_file() and "size scales" in case_path.read_text().splitlines()[0]


def test_bad_withheld_sections_are_named(config, tmp_path):
    bad = copy.deepcopy(config)
    bad["withheld"]["effects"] = ["no_such_effect"]
    with pytest.raises(ValueError, match="config.withheld.effects"):
        withheld.case_names(bad)
    bad = copy.deepcopy(config)
    bad["withheld"]["parameter_draws"] = {"coulomb_friction": {"coulomb_torque_nm": [0.01, 0.02]}}
    with pytest.raises(ValueError, match="parameter_draws.coulomb_friction.coulomb_torque_nm"):
        withheld.draw_case(bad, "s0__single_coulomb_friction__size1")
    bad["withheld"]["parameter_draws"] = {"viscous_friction": {"coefficient_nm_s": 1e-5}}
    with pytest.raises(ValueError, match="parameter_draws.viscous_friction: no size parameter"):
        withheld.draw_case(bad, "s0__single_viscous_friction__size1")
    bad["withheld"]["parameter_draws"] = {"cogging": {"teeth": "size"}}
    with pytest.raises(ValueError, match="parameter_draws.cogging.teeth"):
        withheld.draw_case(bad, "s0__single_cogging__size1")
    bad = copy.deepcopy(config)
    bad["withheld"]["size_range"] = [3.0, 0.1]
    with pytest.raises(ValueError, match="config.withheld.size_range"):
        withheld.case_names(bad)
    with pytest.raises(ValueError, match="is not a case of config.withheld"):
        withheld.draw_case(config, "s7__none")
    with pytest.raises(ValueError, match="unknown withheld case name"):
        withheld.parse_case("single_cogging")
    bad["withheld"]["parameter_draws"] = {}
    bad["withheld"]["size_range"] = [20.0, 30.0]  # an inertia 2.2-2.8 x the nominal one
    with pytest.raises(ValueError, match=r"parameter_draws.inertia_mismatch \(drawn for case s0__single_inertia"):
        withheld.draw_case(bad, "s0__single_inertia_mismatch__size1")
    override = copy.deepcopy(config)
    override["withheld"]["parameter_draws"] = {"cogging": {"order_per_rev": {"choices": [7]}}}
    harmonic, = withheld.draw_case(override, "s0__single_cogging__size1")["parameters"]["cogging"]["harmonics"]
    assert harmonic["order_per_rev"] == 7
