"""The withheld-effect check: cases whose bench has an effect the FMU lacks; does the diagnosis name it?

For every effect of the bench's catalog (and for configured pairs, and for no effect at all) and for every seed
of ``withheld.seeds`` a case config is generated from the main case. Its bench has

- the withheld effect(s), with parameters drawn relative to the main case's ``bench.effects.<effect>`` (the
  demo's): the *size* parameters (torques, coefficients, amplitude, dead time, time offset, inertia deviation)
  are the demo's times a size scale s, log-uniform in ``withheld.size_range``; the *shape* parameters (Stribeck
  and smoothing speeds, current smoothing, cogging order and phase, signs) are drawn independently, so an effect
  never has exactly the demo's shape. ``withheld.sizes_per_effect`` single cases per effect and seed split the
  log range into equal strata with one draw each, so every seed covers the range from well below to well above
  what the diagnosis can detect; pairs and the none case get one case per seed (pairs: s log-uniform over the
  whole range for each of the two effects);
- motor parameter offsets like the demo bench's (``bench.true_parameter_offsets``), each drawn with the demo's
  sign and x ``withheld.offset_scale_range`` of its magnitude, while the FMU keeps its nominal values: the
  diagnosis' parameter-error candidates compete with the withheld effect, as on a real bench.

Each case is emulated (its maneuvers truncated to ``duration_s``), ingested, segmented and diagnosed by the
ordinary stage functions (no calibration, no neural FMU). The diagnosis sees the logs, the FMU and the case
config without its ``bench`` section; only the scoring (:mod:`hybridfmu_bench.withheld.scoring`) reads
the bench's ground truth and the draws, and :mod:`hybridfmu_bench.withheld.report` aggregates the scores
into ``summary.csv``, ``summary.md``, the detection-limit and confusion figures.

Case ids (Snakemake wildcard ``wcase``): ``s<seed>__single_<effect>__size<k>`` (stratum k = 1 .. sizes_per_effect,
1 = the smallest sizes), ``s<seed>__pair_<a>__<b>`` and ``s<seed>__none``.
"""

from __future__ import annotations

import copy
import logging
import math
import re
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from hybridfmu.io import write_json_atomic, write_text_atomic

LOGGER = logging.getLogger("hybridfmu_bench.withheld.suite")

#: How each bench parameter of a withheld effect is drawn, relative to the main case's value of it (the
#: "reference": ``bench.effects.<effect>.<parameter>`` of the main case, else the bench catalog's default):
#:
#: - ``size``: reference x s (s = the case's size scale);
#: - ``signed_size``: random sign x |reference| x s;
#: - ``deviation_size``: 1 + random sign x |reference - 1| x s (a factor around 1);
#: - ``{factor: [lo, hi]}``: reference x a log-uniform factor in [lo, hi] (a shape parameter);
#: - ``{choices: [...]}``: one of the values (uniform); ``{uniform: [lo, hi]}``: uniform in [lo, hi];
#: - a number: that value. A parameter without a draw keeps the reference value.
#:
#: Cogging is drawn as one harmonic; its reference is the main case's strongest harmonic.
#: ``withheld.parameter_draws.<effect>.<parameter>`` overrides an entry.
DEFAULT_PARAMETER_DRAWS: dict[str, dict[str, Any]] = {
    "coulomb_friction": {"coulomb_torque_nm": "size", "breakaway_torque_nm": "size",
                         "stribeck_speed_rad_s": {"factor": [0.5, 2.0]},
                         "smoothing_speed_rad_s": {"factor": [0.5, 2.0]}},
    "viscous_friction": {"coefficient_nm_s": "size"},
    "load_dependent_friction": {"coefficient_apply": "size", "coefficient_release": "size",
                                "smoothing_speed_rad_s": {"factor": [0.5, 2.0]}},
    "cogging": {"amplitude_nm": "size", "order_per_rev": {"choices": [6, 12, 24, 36, 48]},
                "phase_rad": {"uniform": [0.0, 2.0 * math.pi]}},
    "inverter_deadtime": {"deadtime_s": "size", "current_smoothing_a": {"factor": [0.5, 2.0]}},
    "channel_time_offset": {"offset_s": "signed_size"},
    "inertia_mismatch": {"scale": "deviation_size"},
}

SIZE_KINDS = ("size", "signed_size", "deviation_size")
NONE_CASE = "none"
_SEED_RE = re.compile(r"^s(\d+)__(.+)$")
_SINGLE_RE = re.compile(r"^single_([a-z0-9_]+?)__size(\d+)$")
_PAIR_RE = re.compile(r"^pair_([a-z0-9_]+?)__([a-z0-9_]+)$")


def withheld_section(config: dict[str, Any]) -> dict[str, Any]:
    """The ``withheld`` section with defaults (the schema fills them for validated configs)."""
    section = copy.deepcopy(config.get("withheld") or {})
    section.setdefault("duration_s", 6.0)
    section.setdefault("seeds", [0, 1, 2])
    section.setdefault("size_range", [0.1, 3.0])
    section.setdefault("sizes_per_effect", 2)
    section.setdefault("offset_scale_range", [0.5, 1.5])
    section.setdefault("effects", [])
    section.setdefault("pairs", [])
    section.setdefault("none_case", True)
    section.setdefault("parameter_draws", {})
    section.setdefault("maneuvers", {})
    section.setdefault("diagnosis", {})
    section.setdefault("expected", {})
    section.setdefault("targets", {})
    return section


def catalog_effects(section: dict[str, Any]) -> list[str]:
    """The bench effects to withhold: the configured list, or the whole catalog."""
    from hybridfmu_bench.effects import EFFECTS as BENCH_EFFECTS

    names = list(section.get("effects") or BENCH_EFFECTS)
    unknown = [n for n in names if n not in BENCH_EFFECTS]
    if unknown:
        raise ValueError(f"config.withheld.effects: {unknown} are not effects of the bench catalog "
                         f"{sorted(BENCH_EFFECTS)}")
    return names


def _seeds(section: dict[str, Any]) -> list[int]:
    seeds = section["seeds"]
    if not isinstance(seeds, list) or not seeds or any(isinstance(s, bool) or not isinstance(s, int) or s < 0
                                                       for s in seeds):
        raise ValueError(f"config.withheld.seeds: expected a non-empty list of integers >= 0, got {seeds!r}")
    if len(set(seeds)) != len(seeds):
        raise ValueError(f"config.withheld.seeds: seeds listed twice in {seeds}")
    return list(seeds)


def _sizes_per_effect(section: dict[str, Any]) -> int:
    n = section["sizes_per_effect"]
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ValueError(f"config.withheld.sizes_per_effect: expected an integer >= 1, got {n!r}")
    return n


def _positive_range(section: dict[str, Any], key: str) -> tuple[float, float]:
    value = section[key]
    if (not isinstance(value, (list, tuple)) or len(value) != 2
            or any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in value)
            or not 0 < float(value[0]) <= float(value[1])):
        raise ValueError(f"config.withheld.{key}: expected [low, high] with 0 < low <= high, got {value!r}")
    return float(value[0]), float(value[1])


def case_names(config: dict[str, Any]) -> list[str]:
    """Ids of the withheld cases of a config, in a fixed order (seed by seed: singles, pairs, none)."""
    section = withheld_section(config)
    effects = catalog_effects(section)
    n_sizes = _sizes_per_effect(section)
    _positive_range(section, "size_range")
    bases = [f"single_{e}__size{k}" for e in effects for k in range(1, n_sizes + 1)]
    for pair in section["pairs"]:
        if not isinstance(pair, (list, tuple)) or len(pair) != 2 or pair[0] == pair[1]:
            raise ValueError(f"config.withheld.pairs: expected pairs of two different effects, got {pair}")
        catalog_effects({"effects": list(pair)})
        bases.append(f"pair_{pair[0]}__{pair[1]}")
    if section["none_case"]:
        bases.append(NONE_CASE)
    return [f"s{seed}__{base}" for seed in _seeds(section) for base in bases]


#: The keys of ``config.withheld`` that choose which cases exist (a case's own config and draws depend on its id,
#: :func:`case_rng`, not on the other cases).
SELECTION_KEYS = ("seeds", "effects", "pairs", "none_case")


def case_selection(name: str) -> dict[str, Any]:
    """The selection keys (:data:`SELECTION_KEYS`) that make case ``name`` exist and nothing else: its seed, its
    effect (single), its pair, or the none case. A rule that generates one case passes these instead of the suite's,
    so adding a seed, a pair or an effect to the suite leaves the other cases' inputs unchanged."""
    case = parse_case(name)
    return {"seeds": [case.seed], "effects": list(case.effects) if case.kind == "single" else [],
            "pairs": [list(case.effects)] if case.kind == "pair" else [], "none_case": case.kind == "none"}


@dataclass(frozen=True)
class CaseId:
    """A parsed case id: seed, kind (``single``, ``pair``, ``none``), withheld effects, size stratum (singles)."""

    name: str
    seed: int
    kind: str
    effects: tuple[str, ...]
    stratum: int | None = None

    @property
    def base(self) -> str:
        """The id without the seed (the same case in every seed)."""
        return self.name.split("__", 1)[1]


def parse_case(name: str) -> CaseId:
    """Parse a case id (module docstring). Raises ValueError for anything else."""
    match = _SEED_RE.match(name)
    base = match.group(2) if match else ""
    if match and base == NONE_CASE:
        return CaseId(name, int(match.group(1)), "none", ())
    single = _SINGLE_RE.match(base) if match else None
    if single:
        return CaseId(name, int(match.group(1)), "single", (single.group(1),), int(single.group(2)))
    pair = _PAIR_RE.match(base) if match else None
    if pair:
        return CaseId(name, int(match.group(1)), "pair", (pair.group(1), pair.group(2)))
    raise ValueError(f"unknown withheld case name {name!r} (expected s<seed>__single_<effect>__size<k>, "
                     "s<seed>__pair_<a>__<b> or s<seed>__none)")


def case_effects(name: str) -> list[str]:
    """The effects withheld in the case ``name``."""
    return list(parse_case(name).effects)


# ----------------------------------------------------------------------------------------- drawing

def case_rng(master_seed: int, case: CaseId, purpose: str) -> np.random.Generator:
    """The generator of one purpose (``size``, ``shape``, ``offsets``, ``bench``) of a case: seeded by the master
    seed, the case's seed and the case id without its seed, so each draw is reproducible and independent of the
    other cases and purposes."""
    sequence = np.random.SeedSequence([int(master_seed), int(case.seed), zlib.crc32(case.base.encode()),
                                       zlib.crc32(purpose.encode())])
    return np.random.default_rng(sequence)


def stratified_log_uniform(rng: np.random.Generator, low: float, high: float, stratum: int, strata: int) -> float:
    """One draw, log-uniform within stratum ``stratum`` (1-based) of ``strata`` equal parts of [low, high] in
    log scale (stratum 1 holds the smallest values)."""
    if not 1 <= stratum <= strata:
        raise ValueError(f"size stratum {stratum} outside 1..{strata} (config.withheld.sizes_per_effect)")
    a, b = math.log(low), math.log(high)
    u = (stratum - 1 + float(rng.uniform())) / strata
    return float(math.exp(a + u * (b - a)))


def reference_parameters(effect: str, bench: dict[str, Any]) -> dict[str, Any]:
    """The main case's parameters of ``effect`` (``bench.effects.<effect>`` over the catalog's defaults), cogging
    flattened to its strongest harmonic (``order_per_rev``, ``amplitude_nm``, ``phase_rad``)."""
    from hybridfmu_bench.effects import EFFECTS as BENCH_EFFECTS

    values = copy.deepcopy(BENCH_EFFECTS[effect].PARAMETERS)
    configured = dict((bench.get("effects") or {}).get(effect) or {})
    configured.pop("enabled", None)
    values.update(configured)
    if effect == "cogging":
        harmonics = values.get("harmonics") or []
        if not harmonics:
            raise ValueError("config.bench.effects.cogging.harmonics: expected at least one harmonic")
        strongest = max(harmonics, key=lambda h: abs(float(h.get("amplitude_nm", 0.0))))
        return {"order_per_rev": int(strongest.get("order_per_rev", 24)),
                "amplitude_nm": float(strongest.get("amplitude_nm", 0.0)),
                "phase_rad": float(strongest.get("phase_rad", 0.0))}
    return values


def effect_draws(effect: str, section: dict[str, Any]) -> dict[str, Any]:
    """The draw specs of ``effect``: the defaults updated with ``withheld.parameter_draws.<effect>``."""
    draws = copy.deepcopy(DEFAULT_PARAMETER_DRAWS.get(effect, {}))
    override = (section.get("parameter_draws") or {}).get(effect) or {}
    if not isinstance(override, dict):
        raise ValueError(f"config.withheld.parameter_draws.{effect}: expected a mapping parameter -> draw")
    draws.update(override)
    if not any(_size_kind(spec) for spec in draws.values()):
        raise ValueError(f"config.withheld.parameter_draws.{effect}: no size parameter (one of {list(SIZE_KINDS)}); "
                         "the effect's size could not be varied")
    return draws


def _size_kind(spec: Any) -> str | None:
    return spec if isinstance(spec, str) and spec in SIZE_KINDS else None


def draw_value(spec: Any, reference: Any, scale: float, rng: np.random.Generator,
               where: str) -> tuple[Any, float | None]:
    """One parameter value from its draw spec (see ``DEFAULT_PARAMETER_DRAWS``) and the reference value.

    Returns the value and, for a ``factor`` draw, the factor (else None).
    """
    if isinstance(spec, (int, float)) and not isinstance(spec, bool):
        return float(spec), None
    numeric = isinstance(reference, (int, float)) and not isinstance(reference, bool)
    if isinstance(spec, str) and spec in SIZE_KINDS:
        if not numeric:
            raise ValueError(f"{where}: a {spec!r} draw needs a numeric reference value, got {reference!r}")
        if spec == "size":
            return float(reference) * scale, None
        sign = float(rng.choice([-1.0, 1.0]))
        if spec == "signed_size":
            return sign * abs(float(reference)) * scale, None
        return 1.0 + sign * abs(float(reference) - 1.0) * scale, None
    if isinstance(spec, dict) and set(spec) == {"factor"}:
        lo, hi = _pair(spec["factor"], where + ".factor")
        if not numeric or lo <= 0:
            raise ValueError(f"{where}.factor: expected 0 < lo <= hi and a numeric reference, got {spec['factor']!r} "
                             f"and {reference!r}")
        factor = float(math.exp(rng.uniform(math.log(lo), math.log(hi))))
        return float(reference) * factor, factor
    if isinstance(spec, dict) and set(spec) == {"choices"} and isinstance(spec["choices"], list) and spec["choices"]:
        return spec["choices"][int(rng.integers(len(spec["choices"])))], None
    if isinstance(spec, dict) and set(spec) == {"uniform"}:
        lo, hi = _pair(spec["uniform"], where + ".uniform")
        return float(rng.uniform(lo, hi)), None
    raise ValueError(f"{where}: expected size, signed_size, deviation_size, {{factor: [lo, hi]}}, "
                     f"{{choices: [...]}}, {{uniform: [lo, hi]}} or a number, got {spec!r}")


def _pair(value: Any, where: str) -> tuple[float, float]:
    if (not isinstance(value, (list, tuple)) or len(value) != 2
            or any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in value) or value[0] > value[1]):
        raise ValueError(f"{where}: expected [lo, hi] with lo <= hi, got {value!r}")
    return float(value[0]), float(value[1])


def draw_effect_parameters(effect: str, section: dict[str, Any], bench: dict[str, Any], scale: float,
                           rng: np.random.Generator) -> tuple[dict[str, Any], dict[str, float]]:
    """Bench parameters of ``effect`` at size scale ``scale`` (shapes drawn from ``rng``) and the shape factors.

    Returns ``(bench parameters, {parameter: factor})``; cogging's parameters are one harmonic
    (``{"harmonics": [{order_per_rev, amplitude_nm, phase_rad}]}``).
    """
    reference = reference_parameters(effect, bench)
    draws = effect_draws(effect, section)
    values = dict(reference)
    factors = {}
    for key, spec in draws.items():
        where = f"config.withheld.parameter_draws.{effect}.{key}"
        if key not in reference:
            raise ValueError(f"{where}: {effect} has no parameter {key!r}, expected some of {sorted(reference)}")
        values[key], factor = draw_value(spec, reference[key], scale, rng, where)
        if factor is not None:
            factors[key] = factor
    if effect == "cogging":
        order = values["order_per_rev"]
        if isinstance(order, bool) or not isinstance(order, (int, float)) or int(order) != order or order < 1:
            raise ValueError(f"config.withheld.parameter_draws.cogging.order_per_rev: expected positive integers, "
                             f"got {order!r}")
        values = {"harmonics": [{"order_per_rev": int(order), "amplitude_nm": float(values["amplitude_nm"]),
                                 "phase_rad": float(values["phase_rad"])}]}
    return values, factors


def _check_drawn(effect: str, parameters: dict[str, Any], bench: dict[str, Any], name: str) -> None:
    """The bench accepts the drawn parameters (else the error names the draws and the case, not the generated
    config)."""
    from hybridfmu_bench.effects import EFFECTS as BENCH_EFFECTS

    try:
        BENCH_EFFECTS[effect](parameters, pwm_frequency_hz=float(bench.get("pwm_frequency_hz", 10000.0)),
                              where=f"config.withheld.parameter_draws.{effect} (drawn for case {name})")
    except ValueError as err:
        raise ValueError(f"{err}; narrow config.withheld.size_range or the draws of config.withheld.parameter_draws."
                         f"{effect}") from None


def draw_offsets(section: dict[str, Any], bench: dict[str, Any], rng: np.random.Generator) -> dict[str, float]:
    """Motor parameter offsets of a case: each of the main bench's ``true_parameter_offsets`` with its sign and a
    magnitude x U(``withheld.offset_scale_range``) of the main bench's."""
    lo, hi = _positive_range(section, "offset_scale_range")
    offsets = {}
    for name, value in sorted((bench.get("true_parameter_offsets") or {}).items()):
        offsets[name] = float(value) * float(rng.uniform(lo, hi))
    return offsets


def draw_case(config: dict[str, Any], name: str) -> dict[str, Any]:
    """What the bench of case ``name`` has (the draw record written beside the case config, for the scoring only).

    Returns ``case``, ``seed``, ``kind``, ``effects``, ``stratum``, ``strata``, ``size_range``,
    ``offset_scale_range``, ``size_scales`` (effect -> s), ``shape_factors`` (effect -> {parameter: factor}),
    ``reference`` (effect -> the main case's parameters), ``parameters`` (effect -> the bench parameters),
    ``parameter_offsets`` and ``reference_offsets`` (parameter -> relative offset), ``bench_seed``.
    """
    section = withheld_section(config)
    case = parse_case(name)
    if name not in case_names(config):
        raise ValueError(f"case {name!r} is not a case of config.withheld (seeds {section['seeds']}, effects, "
                         "pairs, sizes_per_effect, none_case)")
    bench = config.get("bench")
    if not bench:
        raise ValueError("config.bench: the withheld-effect check needs the main case's bench section "
                         "(sensors, controller, hydraulics, effects and offsets as references) to emulate its cases")
    master = int(config.get("seed", 0))
    low, high = _positive_range(section, "size_range")
    strata = _sizes_per_effect(section)
    size_rng = case_rng(master, case, "size")
    scales = {}
    for effect in case.effects:
        if case.kind == "single":
            scales[effect] = stratified_log_uniform(size_rng, low, high, case.stratum, strata)
        else:
            scales[effect] = float(math.exp(size_rng.uniform(math.log(low), math.log(high))))
    shape_rng = case_rng(master, case, "shape")
    parameters, factors = {}, {}
    for effect in case.effects:
        parameters[effect], factors[effect] = draw_effect_parameters(effect, section, bench, scales[effect], shape_rng)
        _check_drawn(effect, parameters[effect], bench, name)
    return {
        "case": name, "seed": case.seed, "kind": case.kind, "effects": list(case.effects), "stratum": case.stratum,
        "strata": strata if case.kind == "single" else None, "size_range": [low, high],
        "offset_scale_range": list(_positive_range(section, "offset_scale_range")), "size_scales": scales,
        "shape_factors": factors, "reference": {e: reference_parameters(e, bench) for e in case.effects},
        "parameters": parameters,
        "parameter_offsets": draw_offsets(section, bench, case_rng(master, case, "offsets")),
        "reference_offsets": {k: float(v) for k, v in (bench.get("true_parameter_offsets") or {}).items()},
        "bench_seed": int(case_rng(master, case, "bench").integers(0, 2 ** 31 - 1)),
    }


def case_config(config: dict[str, Any], name: str, fmu_path: str | Path,
                draw: dict[str, Any] | None = None) -> dict[str, Any]:
    """The full, validated case config of the withheld case ``name`` derived from the main case ``config``."""
    from hybridfmu.config import validate_case_config

    section = withheld_section(config)
    if not section["maneuvers"]:
        raise ValueError("config.withheld.maneuvers: expected the bench maneuvers of the withheld cases "
                         "(train, validation and test)")
    draw = draw_case(config, name) if draw is None else draw
    results_dir = f"{config.get('results_dir', 'results')}/withheld"
    case = copy.deepcopy(config)
    case.pop("withheld", None)
    case["case"] = name
    case["results_dir"] = results_dir
    case["seed"] = int(config.get("seed", 0))
    case["fmu"] = {**copy.deepcopy(config["fmu"]), "source": "path", "path": str(fmu_path)}
    bench = case["bench"]
    bench["seed"] = draw["bench_seed"]
    bench["true_parameter_offsets"] = dict(draw["parameter_offsets"])
    bench["effects"] = copy.deepcopy(draw["parameters"])
    bench["maneuvers"] = copy.deepcopy(section["maneuvers"])
    case["maneuvers"] = {m: {"role": spec.get("role", m), "raw": f"{results_dir}/{name}/raw/{m}.mf4"}
                         for m, spec in section["maneuvers"].items()}
    for m in case["maneuvers"]:
        bench["maneuvers"][m].pop("role", None)
    diagnosis = copy.deepcopy(config.get("diagnosis", {}))
    _deep_update(diagnosis, section.get("diagnosis") or {})
    case["diagnosis"] = diagnosis
    validate_case_config(case)
    return case


def _deep_update(target: dict[str, Any], update: dict[str, Any]) -> None:
    for key, value in update.items():
        if isinstance(value, dict) and isinstance(target.get(key), dict):
            _deep_update(target[key], value)
        else:
            target[key] = copy.deepcopy(value)


def write_case_config(config: dict[str, Any], name: str, fmu_path: str | Path, out_path: str | Path,
                      draw_path: str | Path | None = None, duration_s: float | None = None) -> dict[str, Any]:
    """Write the case config of ``name`` (YAML, with the truncation of its maneuvers as a comment) and, with
    ``draw_path``, the draw record (:func:`draw_case`, JSON) the scoring reads."""
    draw = draw_case(config, name)
    case = case_config(config, name, fmu_path, draw)
    duration = withheld_section(config)["duration_s"] if duration_s is None else duration_s
    scales = ", ".join(f"{e} x{s:.3g}" for e, s in draw["size_scales"].items()) or "no effect"
    header = (f"# Withheld-effect case {name!r}: the bench has {scales} (size scales against the main case's "
              f"effects) and parameter offsets {draw['parameter_offsets']}; the FMU lacks them.\n"
              f"# Generated from the main case {config.get('case')!r}; maneuvers truncated to {duration:g} s.\n")
    if draw_path is not None:
        write_json_atomic(draw_path, draw)
    write_text_atomic(out_path, header + yaml.safe_dump(case, sort_keys=False))
    return case


def load_case(path: str | Path) -> dict[str, Any]:
    """Read and validate a generated case config."""
    from hybridfmu.config import load_case_config

    return load_case_config(path)


def without_bench(case: dict[str, Any]) -> dict[str, Any]:
    """The case config the data stages and the diagnosis get: everything but the bench (the ground truth)."""
    return {key: value for key, value in case.items() if key != "bench"}


def emulate_case(case_path: str | Path, maneuver: str, mdf_path: str | Path, truth_path: str | Path,
                 duration_s: float) -> dict[str, Any]:
    """Emulate one (truncated) maneuver of a withheld case."""
    from hybridfmu_bench.emulate import emulate_bench

    case = load_case(case_path)
    return emulate_bench(case, maneuver, mdf_path, truth_path, duration_s=duration_s,
                         check_spread_of_maneuvers=False)


def ingest_case(case_path: str | Path, raw_path: str | Path, out_path: str | Path) -> None:
    """Ingest one raw log of a withheld case with the case's ingest settings."""
    from hybridfmu.data.ingest import ingest_to_parquet

    ingest_to_parquet(raw_path, out_path, without_bench(load_case(case_path)), maneuver=Path(raw_path).stem)


def segment_case(case_path: str | Path, data_path: str | Path, json_path: str | Path, png_path: str | Path,
                 maneuver: str) -> None:
    """Select the segments of one ingested maneuver of a withheld case."""
    from hybridfmu.data.segments_stage import select_segments_to_files

    select_segments_to_files(data_path, json_path, png_path, maneuver, without_bench(load_case(case_path)))


def diagnose_case(case_path: str | Path, fmu_path: str | Path, data_paths: dict[str, str | Path],
                  segments_paths: dict[str, str | Path], out_dir: str | Path) -> dict[str, Any]:
    """Diagnose a withheld case: the FMU with its nominal parameters (the bench's differ by the case's offsets), no
    calibration, no neural FMU, no MLflow run; the diagnosis never sees the case's bench section."""
    from hybridfmu.diagnosis.report import diagnose

    case = without_bench(load_case(case_path))
    return diagnose(case, fmu_path, data_paths, segments_paths, out_dir, mlflow=False)

