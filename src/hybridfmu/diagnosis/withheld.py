"""The withheld-effect check: cases whose bench has an effect the FMU lacks; does the diagnosis name it?

For every effect of the bench's catalog (and for configured pairs, and for no effect at all) a
case config is generated from the main case: the bench's true motor parameters equal the FMU's
nominal ones (no parameter offsets), only the withheld effect(s) are switched on with parameters
drawn (seeded) from documented ranges, and the maneuvers are the short ones of the ``withheld``
section. Each case is emulated, ingested, segmented and diagnosed by the ordinary stage
functions (no neural FMU); ``summarise`` compares what was found with the ground truth (the only
place that reads it) and writes ``summary.csv``, a confusion-matrix plot and ``summary.md``.

The bench names its effects (coulomb_friction, cogging, ...), the diagnosis names generic terms over
roles (``coulomb(<state>)``, ``periodic(<state>)``, ...). The table ``withheld.expected`` of the config maps
each bench effect to fnmatch patterns of diagnosis effect names (``{bench effect: [patterns]}``); a
named effect counts as the bench effect whose pattern it matches. No mapping lives in code.
"""

from __future__ import annotations

import copy
import csv
import fnmatch
import io
import json
import logging
import math
import zlib
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from hybridfmu.io import read_json, write_text_atomic

LOGGER = logging.getLogger("hybridfmu.diagnosis.withheld")

#: Parameter ranges of the withheld effects (bench parameter names). A list [lo, hi] is drawn uniformly;
#: {choices: [...]} picks one; {around: c, magnitude: [lo, hi]} gives c +- a uniform magnitude (random sign).
#: The ranges make each effect matter for the open-loop simulation: its open-loop angle error on the test
#: maneuver is clearly above the no-effect level (~2e-3 rad). Weaker effects (e.g. a viscous coefficient of
#: 1e-4 N m s or an offset of 2e-5 s) are still named, but leave no gap to shrink.
DEFAULT_PARAMETER_RANGES: dict[str, dict[str, Any]] = {
    "coulomb_friction": {"coulomb_torque_nm": [0.025, 0.05], "breakaway_torque_nm": [0.06, 0.09],
                         "stribeck_speed_rad_s": [2.0, 6.0]},
    "viscous_friction": {"coefficient_nm_s": [2.5e-4, 4.0e-4]},
    "load_dependent_friction": {"coefficient_apply": [0.06, 0.12], "coefficient_release": [0.04, 0.10]},
    "cogging": {"order_per_rev": {"choices": [12, 24, 36]}, "amplitude_nm": [0.01, 0.02],
                "phase_rad": [0.0, 6.283]},
    "inverter_deadtime": {"deadtime_s": [5.0e-7, 1.5e-6]},
    "channel_time_offset": {"offset_s": {"around": 0.0, "magnitude": [1.0e-4, 1.5e-4]}},
    "inertia_mismatch": {"scale": {"around": 1.0, "magnitude": [0.08, 0.2]}},
}

#: Names of the checked cases: single_<effect>, pair_<a>__<b>, none.
NONE_CASE = "none"


def withheld_section(config: dict[str, Any]) -> dict[str, Any]:
    """The ``withheld`` section with defaults (the schema fills them for validated configs)."""
    section = copy.deepcopy(config.get("withheld") or {})
    section.setdefault("duration_s", 6.0)
    section.setdefault("seed", 0)
    section.setdefault("effects", [])
    section.setdefault("pairs", [])
    section.setdefault("none_case", True)
    section.setdefault("parameter_ranges", {})
    section.setdefault("maneuvers", {})
    section.setdefault("diagnosis", {})
    section.setdefault("expected", {})
    return section


def catalog_effects(section: dict[str, Any]) -> list[str]:
    """The bench effects to withhold: the configured list, or the whole catalog."""
    from hybridfmu.bench.effects import EFFECTS as BENCH_EFFECTS

    names = list(section.get("effects") or BENCH_EFFECTS)
    unknown = [n for n in names if n not in BENCH_EFFECTS]
    if unknown:
        raise ValueError(f"config.withheld.effects: {unknown} are not effects of the bench catalog "
                         f"{sorted(BENCH_EFFECTS)}")
    return names


def case_names(config: dict[str, Any]) -> list[str]:
    """Names of the withheld cases of a config, in a fixed order."""
    section = withheld_section(config)
    names = [f"single_{e}" for e in catalog_effects(section)]
    for pair in section["pairs"]:
        if len(pair) != 2:
            raise ValueError(f"config.withheld.pairs: expected pairs of two effects, got {pair}")
        catalog_effects({"effects": list(pair)})
        names.append(f"pair_{pair[0]}__{pair[1]}")
    if section["none_case"]:
        names.append(NONE_CASE)
    return names


def case_effects(name: str) -> list[str]:
    """The effects withheld in the case ``name``."""
    if name == NONE_CASE:
        return []
    if name.startswith("single_"):
        return [name[len("single_"):]]
    if name.startswith("pair_"):
        return name[len("pair_"):].split("__")
    raise ValueError(f"unknown withheld case name {name!r} (expected single_<effect>, pair_<a>__<b> or none)")


def draw_value(spec: Any, rng: np.random.Generator, where: str) -> Any:
    """One parameter value from its range spec (see ``DEFAULT_PARAMETER_RANGES``)."""
    if isinstance(spec, (int, float)) and not isinstance(spec, bool):
        return float(spec)
    if isinstance(spec, list) and len(spec) == 2:
        return float(rng.uniform(float(spec[0]), float(spec[1])))
    if isinstance(spec, dict) and "choices" in spec:
        return spec["choices"][int(rng.integers(len(spec["choices"])))]
    if isinstance(spec, dict) and "around" in spec and "magnitude" in spec:
        lo, hi = spec["magnitude"]
        return float(spec["around"]) + float(rng.choice([-1.0, 1.0])) * float(rng.uniform(lo, hi))
    raise ValueError(f"{where}: expected [lo, hi], {{choices: [...]}} or {{around: c, magnitude: [lo, hi]}}, "
                     f"got {spec!r}")


def draw_effect_parameters(effect: str, ranges: dict[str, Any], rng: np.random.Generator) -> dict[str, Any]:
    """Bench parameters of ``effect`` drawn from ``ranges`` (cogging becomes one harmonic)."""
    where = f"config.withheld.parameter_ranges.{effect}"
    values = {key: draw_value(spec, rng, f"{where}.{key}") for key, spec in ranges.items()}
    if effect == "cogging":
        return {"harmonics": [{"order_per_rev": int(values.get("order_per_rev", 24)),
                               "amplitude_nm": float(values.get("amplitude_nm", 0.01)),
                               "phase_rad": float(values.get("phase_rad", 0.0))}]}
    return values


def case_config(config: dict[str, Any], name: str, fmu_path: str | Path) -> dict[str, Any]:
    """The full, validated case config of the withheld case ``name`` derived from the main case ``config``."""
    from hybridfmu.config import validate_case_config

    section = withheld_section(config)
    if "bench" not in config:
        raise ValueError("config.bench: the withheld-effect check needs the main case's bench section "
                         "(sensors, controller, hydraulics) to emulate its cases")
    if not section["maneuvers"]:
        raise ValueError("config.withheld.maneuvers: expected the bench maneuvers of the withheld cases "
                         "(train, validation and test)")
    ranges = copy.deepcopy(DEFAULT_PARAMETER_RANGES)
    for effect, override in (section.get("parameter_ranges") or {}).items():
        ranges.setdefault(effect, {}).update(override)
    master = int(config.get("seed", 0))
    rng = np.random.default_rng(np.random.SeedSequence([master, int(section["seed"]), zlib.crc32(name.encode())]))
    effects = {}
    for effect in case_effects(name):
        if effect not in ranges:
            raise ValueError(f"config.withheld.parameter_ranges: no range for effect {effect!r}")
        effects[effect] = draw_effect_parameters(effect, ranges[effect], rng)
    results_dir = f"{config.get('results_dir', 'results')}/withheld"
    case = copy.deepcopy(config)
    case.pop("withheld", None)
    case["case"] = name
    case["results_dir"] = results_dir
    case["seed"] = master
    case["fmu"] = {**copy.deepcopy(config["fmu"]), "source": "path", "path": str(fmu_path)}
    bench = case["bench"]
    bench["seed"] = int(rng.integers(0, 2 ** 31 - 1))
    bench["true_parameter_offsets"] = {}
    bench["effects"] = effects
    bench["maneuvers"] = copy.deepcopy(section["maneuvers"])
    case["maneuvers"] = {m: {"role": spec.get("role", m), "raw": f"{results_dir}/{name}/raw/{m}.mf4"}
                         for m, spec in section["maneuvers"].items()}
    for m in case["maneuvers"]:
        case["bench"]["maneuvers"][m].pop("role", None)
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
                      duration_s: float | None = None) -> dict[str, Any]:
    """Write the case config of ``name`` (YAML, with the truncation of its maneuvers as a comment)."""
    case = case_config(config, name, fmu_path)
    duration = withheld_section(config)["duration_s"] if duration_s is None else duration_s
    header = (f"# Withheld-effect case {name!r}: the bench has {case_effects(name) or 'no effect'}, the FMU lacks it.\n"
              f"# Generated from the main case {config.get('case')!r}; maneuvers truncated to {duration:g} s.\n")
    write_text_atomic(out_path, header + yaml.safe_dump(case, sort_keys=False))
    return case


def load_case(path: str | Path) -> dict[str, Any]:
    """Read and validate a generated case config."""
    from hybridfmu.config import load_case_config

    return load_case_config(path)


def emulate_case(case_path: str | Path, maneuver: str, mdf_path: str | Path, truth_path: str | Path,
                 duration_s: float) -> dict[str, Any]:
    """Emulate one (truncated) maneuver of a withheld case."""
    from hybridfmu.bench.emulate import emulate_bench

    case = load_case(case_path)
    return emulate_bench(case, maneuver, mdf_path, truth_path, duration_s=duration_s,
                         check_spread_of_maneuvers=False)


def ingest_case(case_path: str | Path, raw_path: str | Path, out_path: str | Path) -> None:
    """Ingest one raw log of a withheld case with the case's ingest settings."""
    from hybridfmu.data.ingest import ingest_to_parquet

    ingest_to_parquet(raw_path, out_path, load_case(case_path), maneuver=Path(raw_path).stem)


def segment_case(case_path: str | Path, data_path: str | Path, json_path: str | Path, png_path: str | Path,
                 maneuver: str) -> None:
    """Select the segments of one ingested maneuver of a withheld case."""
    from hybridfmu.data.segments import select_segments_to_files

    select_segments_to_files(data_path, json_path, png_path, maneuver, load_case(case_path))


def diagnose_case(case_path: str | Path, fmu_path: str | Path, data_paths: dict[str, str | Path],
                  segments_paths: dict[str, str | Path], out_dir: str | Path) -> dict[str, Any]:
    """Diagnose a withheld case (the FMU with its nominal parameters: the bench's true ones; no calibration,
    no neural FMU, no MLflow run)."""
    from hybridfmu.diagnosis.report import diagnose

    case = load_case(case_path)
    return diagnose(case, fmu_path, data_paths, segments_paths, out_dir, best_json=None, mlflow=False)


# ----------------------------------------------------------------------------------------- summary

def _truth_parameters(truth: dict[str, Any]) -> dict[str, Any]:
    return {effect["name"]: effect["parameters"] for effect in truth.get("effects", [])}


def _fitted_parameters(record: dict[str, Any]) -> dict[str, Any]:
    out = {}
    for item in record["which"]["chosen"]:
        out[f"{item['effect']} in d{item['equation']}/dt"] = {p["name"]: p["value"] for p in item["parameters"]}
    return out


def bench_effect_of(name: str, expected: dict[str, list[str]]) -> str | None:
    """The bench effect whose patterns (``withheld.expected``) match the diagnosis effect ``name``, or None."""
    for bench_effect, patterns in expected.items():
        if any(fnmatch.fnmatchcase(name, p) for p in patterns):
            return bench_effect
    return None


def case_row(name: str, record: dict[str, Any], truth: dict[str, Any],
             expected: dict[str, list[str]] | None = None) -> dict[str, Any]:
    """One row of ``summary.csv``: the named effects translated to bench effects through ``expected``.

    Named effects that match no pattern are kept under their own name (they count as spurious).
    """
    expected = expected or {}
    true_effects = [e["name"] for e in truth.get("effects", [])]
    named = list(record["which"]["found_effects"])
    found = list(dict.fromkeys(bench_effect_of(n, expected) or n for n in named))
    if not true_effects:
        correct = not found
    elif len(true_effects) == 1:
        correct = bool(found) and found[0] == true_effects[0]
    else:
        correct = all(e in found for e in true_effects)
    far = record.get("how_far") or {}
    before, after = far.get("gap_before"), far.get("gap_after")
    shrink = before / after if before is not None and after not in (None, 0) else None
    ratios = {k: v.get("ratio_to_noise") for k, v in record["where"]["equations"]["states"].items()}
    return {
        "case": name, "true_effects": ";".join(true_effects) or "none",
        "true_params": json.dumps(_truth_parameters(truth), sort_keys=True),
        "found_effects": ";".join(found) or "none", "named_effects": ";".join(named) or "none", "correct": correct,
        "fitted_params": json.dumps(_fitted_parameters(record), sort_keys=True, default=float),
        "gap_before": before, "gap_after": after, "shrink_factor": shrink,
        "window_gap_before": far.get("window_gap_before"), "window_gap_after": far.get("window_gap_after"),
        "ratio_to_noise": json.dumps(ratios, sort_keys=True, default=float),
    }


SUMMARY_COLUMNS = ["case", "true_effects", "true_params", "found_effects", "named_effects", "correct", "fitted_params",
                   "gap_before", "gap_after", "shrink_factor", "window_gap_before", "window_gap_after",
                   "ratio_to_noise"]


def confusion_matrix(rows: list[dict[str, Any]]) -> tuple[list[str], np.ndarray]:
    """Detection matrix over the cases, rows = withheld effect, columns = named effect (same labels, "none" last).

    Per case: a withheld effect that was named counts on the diagonal, one that was missed in the
    "none" column; a named effect that was not withheld counts in the "none" row; a case without
    effects that names nothing counts at ("none", "none").
    """
    effects = sorted({e for r in rows for key in ("true_effects", "found_effects")
                      for e in r[key].split(";")} - {"none"})
    labels = effects + ["none"]
    matrix = np.zeros((len(labels), len(labels)), dtype=int)
    for r in rows:
        true = [e for e in r["true_effects"].split(";") if e != "none"]
        found = [e for e in r["found_effects"].split(";") if e != "none"]
        for effect in true:
            column = effect if effect in found else "none"
            matrix[labels.index(effect), labels.index(column)] += 1
        for effect in found:
            if effect not in true:
                matrix[labels.index("none"), labels.index(effect)] += 1
        if not true and not found:
            matrix[labels.index("none"), labels.index("none")] += 1
    return labels, matrix


def confusion_figure(rows: list[dict[str, Any]], path: Path, dpi: int = 120) -> Path:
    """Confusion matrix of withheld (rows) against found (columns) effects."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from hybridfmu.io import atomic_path

    labels, matrix = confusion_matrix(rows)
    fig, ax = plt.subplots(figsize=(2.5 + 0.8 * len(labels), 1.8 + 0.6 * len(labels)))
    ax.imshow(matrix, cmap="Blues", vmin=0, vmax=max(int(matrix.max()), 1))
    for i in range(matrix.shape[0]):
        for j in range(matrix.shape[1]):
            if matrix[i, j]:
                ax.text(j, i, str(matrix[i, j]), ha="center", va="center",
                        color="white" if matrix[i, j] > matrix.max() / 2 else "black")
    ax.set_xticks(range(len(labels)), labels, rotation=40, ha="right", fontsize=8)
    ax.set_yticks(range(len(labels)), labels, fontsize=8)
    ax.set_xlabel("effect named by the diagnosis (none = missed)")
    ax.set_ylabel("effect withheld from the FMU (none = named although not withheld)")
    ax.set_title("Withheld-effect check: detections over all cases", fontsize=10)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    plt.close(fig)
    return path


def _fmt(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return f"{value:.6g}" if math.isfinite(value) else ""
    return str(value)


def summarise(names: list[str], diagnosis_paths: list[str | Path], truth_paths: list[str | Path],
              csv_path: str | Path, figure_path: str | Path, markdown_path: str | Path,
              expected: dict[str, list[str]] | None = None) -> list[dict[str, Any]]:
    """Compare every case's diagnosis with its ground truth; write the CSV, the confusion plot and a markdown
    table with the targets' verdicts. ``truth_paths``: one truth file (any maneuver) per case; ``expected``:
    the ``withheld.expected`` table (bench effect -> diagnosis effect name patterns)."""
    rows = [case_row(n, read_json(d), read_json(t), expected) for n, d, t in zip(names, diagnosis_paths, truth_paths)]
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=SUMMARY_COLUMNS)
    writer.writeheader()
    for row in rows:
        writer.writerow({k: _fmt(row[k]) for k in SUMMARY_COLUMNS})
    write_text_atomic(csv_path, buffer.getvalue())
    confusion_figure(rows, Path(figure_path))
    write_text_atomic(markdown_path, summary_markdown(rows))
    return rows


def targets(rows: list[dict[str, Any]]) -> dict[str, bool]:
    """The check's targets: single cases top-1 correct, pairs both found, none case names nothing,
    gap shrinks >= 3x wherever correct (cases with effects)."""
    singles = [r for r in rows if r["case"].startswith("single_")]
    pairs = [r for r in rows if r["case"].startswith("pair_")]
    nones = [r for r in rows if r["case"] == NONE_CASE]
    shrink = [r for r in rows if r["correct"] and r["true_effects"] != "none"]
    return {
        "single_top1_correct": all(r["correct"] for r in singles),
        "pairs_both_found": all(r["correct"] for r in pairs),
        "none_names_nothing": all(r["correct"] for r in nones),
        "gap_shrinks_3x_where_correct": all(r["shrink_factor"] is not None and r["shrink_factor"] >= 3.0
                                            for r in shrink),
    }


def summary_markdown(rows: list[dict[str, Any]]) -> str:
    """Markdown table of the cases and the targets."""
    lines = ["# Withheld-effect check", "",
             "| case | withheld | named (rank order) | as bench effects | correct | gap before | gap after | shrink |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['case']} | {r['true_effects']} | {r['named_effects']} | {r['found_effects']} | "
                     f"{r['correct']} | {_fmt(r['gap_before'])} | {_fmt(r['gap_after'])} | {_fmt(r['shrink_factor'])} |")
    lines += ["", "Targets:", ""] + [f"- {k}: {'met' if v else 'NOT met'}" for k, v in targets(rows).items()]
    lines += ["", "gap = normalised open-loop error over the whole held-out test maneuver (target-weighted MAE over "
                  "each target's spread); named effects are translated to bench effects by withheld.expected.", ""]
    return "\n".join(lines)
