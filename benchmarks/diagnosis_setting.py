"""A diagnosis setting or the diagnosis code changed, side by side with the withheld suite's own diagnoses, on the
calibration seeds.

Every setting of the demo's ``diagnosis`` section that differs from the schema's default needs a reason that is not
the bench; this script measures what a change does before anyone makes it. For every case of a finished withheld
suite (``snakemake -j2 withheld``) on the calibration seeds (``withheld.calibration_seeds``; the evaluation seeds
are never read), it diagnoses the case again with the changed setting (``--set diagnosis.KEY=VALUE``, a YAML
value; ``default`` removes the key, so the schema's default applies) and scores both diagnoses with the suite's
own scoring (:func:`hybridfmu_bench.withheld.scoring.score_case`; detection limits set on each variant's own cases,
as the suite does). Without ``--set`` the variant is the code of this checkout (its commit, with local changes if
any) against the code that diagnosed the suite: a change of the diagnosis' code measured the same way. The changed
diagnoses go to ``--out`` (default ``<withheld>_settings/<change>``, for code ``code-<commit>``); a case already
diagnosed there with the same case config is not diagnosed again. ``--against SUITE`` diagnoses nothing: the changed
diagnoses are those of another finished suite of the same draws (the same cases rerun at another code or config;
the block names the diagnosis settings in which the two suites' case configs differ).

Prints a table; the last line is a JSON object with the figures. ``--markdown FILE`` writes the table for the
documentation.

    python benchmarks/diagnosis_setting.py [--set diagnosis.kernel_s=default --set diagnosis.smoothing_s=default]
        [--config config/config.yaml] [--withheld results/withheld] [--cases PATTERN] [--jobs 2] [--out DIR]
        [--markdown FILE] [--against OTHER_SUITE]
"""

from __future__ import annotations

import argparse
import fnmatch
import json
import logging
import multiprocessing
import re
import statistics
import time
from pathlib import Path
from typing import Any

import yaml

from hybridfmu.config import load_case_config
from hybridfmu.io import read_json, write_text_atomic
from hybridfmu.tracking.provenance import code_version, describe
from hybridfmu_bench.withheld.report import code_versions

ROOT = Path(__file__).resolve().parents[1]
LOG = logging.getLogger("diagnosis_setting")


def parse_change(text: str) -> tuple[list[str], Any]:
    """``diagnosis.a.b=VALUE`` -> (["a", "b"], the YAML value, or the marker ``default``)."""
    key, sep, value = text.partition("=")
    parts = key.strip().split(".")
    if not sep or parts[0] != "diagnosis" or len(parts) < 2 or not all(parts):
        raise SystemExit(f"--set {text!r}: expected diagnosis.KEY[.SUBKEY]=VALUE (a YAML value, or default)")
    return parts[1:], ("default" if value.strip() == "default" else yaml.safe_load(value))


def apply_changes(diagnosis: dict[str, Any], changes: list[tuple[list[str], Any]]) -> dict[str, Any]:
    """A copy of a case's ``diagnosis`` section with the changes made (``default``: the key removed)."""
    out = json.loads(json.dumps(diagnosis))
    for path, value in changes:
        node = out
        for key in path[:-1]:
            node = node.setdefault(key, {})
        if value == "default":
            node.pop(path[-1], None)
        else:
            node[path[-1]] = value
    return out


def _diagnose(job: tuple[str, Path, Path, Path, list]) -> dict[str, Any]:
    """Diagnose one case with the changes (unless already done with the same case config); its run time."""
    from hybridfmu_bench.withheld.suite import diagnose_case

    case, withheld, fmu, out, changes = job
    config = yaml.safe_load((withheld / "cases" / f"{case}.yaml").read_text())
    config["diagnosis"] = apply_changes(config.get("diagnosis") or {}, changes)
    folder = out / case
    case_path, result = folder / "case.yaml", folder / "diagnosis" / "diagnosis.json"
    text = yaml.safe_dump(config, sort_keys=True)
    started = time.perf_counter()
    if not (result.is_file() and case_path.is_file() and case_path.read_text() == text):
        folder.mkdir(parents=True, exist_ok=True)
        write_text_atomic(case_path, text)
        maneuvers = list(config["maneuvers"])
        diagnose_case(case_path, fmu, {m: withheld / case / "data" / f"{m}.parquet" for m in maneuvers},
                      {m: withheld / case / "segments" / f"{m}.json" for m in maneuvers}, folder / "diagnosis")
    return {"case": case, "seconds": time.perf_counter() - started}


def _settings_differences(old: dict[str, Any], new: dict[str, Any], prefix: str = "diagnosis") -> list[str]:
    """The keys (dotted) in which two ``diagnosis`` sections differ, each as ``key=new value`` (``default`` when the
    new section leaves the key out)."""
    out = []
    for key in sorted(set(old) | set(new)):
        path = f"{prefix}.{key}"
        if key not in new:
            out.append(f"{path}=default")
        elif isinstance(old.get(key), dict) and isinstance(new[key], dict):
            out.extend(_settings_differences(old[key], new[key], path))
        elif old.get(key) != new[key]:
            out.append(f"{path}={json.dumps(new[key])}")
    return out


def _without_run_times(record: Any) -> Any:
    """A JSON record without the wall-clock times it carries (keys ending in ``wall_s``): what two runs of the same
    emulation share."""
    if isinstance(record, dict):
        return {k: _without_run_times(v) for k, v in record.items() if not k.endswith("wall_s")}
    if isinstance(record, list):
        return [_without_run_times(v) for v in record]
    return record


def against_suite(withheld: Path, other: Path, cases: list[str]) -> list[str]:
    """Check that ``other`` holds the same finished cases as ``withheld`` (the same draws and the same emulated
    truths, but for their run times) and return the diagnosis settings in which their case configs differ (one list for every case; an error
    when cases differ in different ways)."""
    differences = set()
    for case in cases:
        for part in (Path("cases") / f"{case}.draw.json", *sorted(p.relative_to(withheld) for p in
                                                               (withheld / case / "raw").glob("*.truth.json"))):
            if not (other / part).is_file() or (_without_run_times(read_json(other / part))
                                                != _without_run_times(read_json(withheld / part))):
                raise SystemExit(f"{other / part}: missing or not the same as {withheld / part}; --against needs a "
                                 "suite of the same draws and bench")
        if not (other / case / "diagnosis" / "diagnosis.json").is_file():
            raise SystemExit(f"{other / case / 'diagnosis' / 'diagnosis.json'}: missing; finish that suite first")
        old, new = (yaml.safe_load((root / "cases" / f"{case}.yaml").read_text()).get("diagnosis") or {}
                    for root in (withheld, other))
        differences.add(tuple(_settings_differences(old, new)))
    if len(differences) > 1:
        raise SystemExit(f"{other}: its cases' diagnosis settings differ from {withheld}'s in different ways: "
                         f"{sorted(differences)}")
    return list(differences.pop()) if differences else []


def score(cases: list[str], diagnoses: dict[str, Path], withheld: Path, expected: dict,
          background: dict, targets: dict) -> dict[str, Any]:
    """The suite's measures (:func:`hybridfmu_bench.withheld.report.aggregate`) of one variant's diagnoses, with the
    detection limits set on its own cases, the median parameter error per bench effect, the effects each case names
    and the kernel lengths (samples) the diagnoses used."""
    import numpy as np
    import pandas as pd

    from hybridfmu.diagnosis.derivatives import odd_window
    from hybridfmu.io import read_json
    from hybridfmu_bench.withheld.report import aggregate, detection_limits, per_effect_errors
    from hybridfmu_bench.withheld.scoring import score_case

    rows, kernels = [], []
    for case in cases:
        record = read_json(diagnoses[case])
        maneuvers = list(record["maneuvers"])
        truth = read_json(withheld / case / "raw" / f"{maneuvers[-1]}.truth.json")
        rows.append(score_case(record, truth, read_json(withheld / "cases" / f"{case}.draw.json"), expected,
                               background))
        time_s = pd.read_parquet(withheld / case / "data" / f"{maneuvers[0]}.parquet", columns=["time_s"])["time_s"]
        kernels.append(odd_window(float(record["method"]["kernel_s"]), float(np.median(np.diff(time_s.to_numpy())))))
    limits = detection_limits(rows)
    measures = aggregate(rows, limits, targets)
    above = set(measures["above_cases"])
    per_effect = {effect: item["median"]
                  for effect, item in per_effect_errors([r for r in rows if r["case"] in above]).items()}
    named = {row["case"]: sorted(row["named_effects"]) for row in rows}
    return {"measures": measures, "per_effect": per_effect, "named": named,
            "kernel_samples": {"median": statistics.median(kernels), "min": min(kernels), "max": max(kernels)}}


def _pct(value: Any) -> str:
    return "–" if value is None else f"{100.0 * value:.0f} %"


def _num(value: Any) -> str:
    return "–" if value is None else f"{value:.3g}"


def _factor(value: Any) -> str:
    return "–" if value is None else f"×{value:.3g}"


def _covered(entry: dict[str, int] | None) -> str:
    return "–" if not entry else f"{entry['covered']}/{entry['n']}"


def _span(values: dict[str, float]) -> str:
    return f"{_num(values['median'])} [{_num(values['min'])} – {_num(values['max'])}]"


def markdown(summary: dict[str, Any]) -> str:
    """The comparison as a Markdown block."""
    base, changed = summary["suite"], summary["changed"]
    b, c = base["measures"], changed["measures"]
    command = " ".join(["python benchmarks/diagnosis_setting.py", summary["arguments"]]).strip()
    lines = [f"Withheld suite, calibration seeds ({summary['n_cases']} cases): the suite's diagnoses (the code at "
             f"{summary['suite_code']}) against the same cases diagnosed with {summary['change']} (`{command}`; "
             "detection limits set on each variant's own cases).", "",
             "| measure | the suite's | changed |", "|---|---|---|",
             f"| kernel length (samples), median [min – max] | {_span(base['kernel_samples'])} | "
             f"{_span(changed['kernel_samples'])} |",
             f"| exact set, cases above the limits | {_pct(b['exact_set_accuracy'])} ({b['n_exact']}/{b['n_above']}) | "
             f"{_pct(c['exact_set_accuracy'])} ({c['n_exact']}/{c['n_above']}) |",
             f"| exact set, every case with effects | {_pct(b['exact_set_accuracy_all'])} "
             f"({b['n_exact_all']}/{b['n_with_effects']}) | {_pct(c['exact_set_accuracy_all'])} "
             f"({c['n_exact_all']}/{c['n_with_effects']}) |",
             f"| median parameter error, cases above the limits | {_num(b['median_parameter_error_pct'])} % | "
             f"{_num(c['median_parameter_error_pct'])} % |",
             f"| none cases naming nothing | {b['none_clean']}/{b['n_none']} | {c['none_clean']}/{c['n_none']} |",
             f"| median windowed shrink of the named effects on top of the parameter corrections, exact cases | "
             f"{_factor(b.get('median_window_effect_shrink_exact'))} | "
             f"{_factor(c.get('median_window_effect_shrink_exact'))} |",
             f"| largest windowed shrink of the named effects, none cases | "
             f"{_factor(b.get('max_window_effect_shrink_none'))} | {_factor(c.get('max_window_effect_shrink_none'))} |",
             f"| cases naming what the suite's diagnosis names | – | "
             f"{sum(changed['named'][case] == base['named'][case] for case in base['named'])}/{len(base['named'])} |"]
    for effect in sorted(set(base["per_effect"]) | set(changed["per_effect"])):
        lines.append(f"| median parameter error, {effect} | {_num(base['per_effect'].get(effect))} % | "
                     f"{_num(changed['per_effect'].get(effect))} % |")
    base_cover, changed_cover = b["interval_coverage"], c["interval_coverage"]
    for effect in sorted(set(base_cover) | set(changed_cover)):
        lines.append(f"| 90 % intervals containing the truth, {effect} | {_covered(base_cover.get(effect))} | "
                     f"{_covered(changed_cover.get(effect))} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--set", dest="changes", action="append", default=[],
                        help="diagnosis.KEY[.SUBKEY]=VALUE (YAML; default: the schema's default); repeatable; none: "
                             "the code of this checkout against the suite's")
    parser.add_argument("--config", type=Path, default=ROOT / "config" / "config.yaml")
    parser.add_argument("--withheld", type=Path, default=None, help="the suite's folder (default <results>/withheld)")
    parser.add_argument("--cases", default=None, help="fnmatch pattern of case names (default: the calibration "
                                                       "seeds' cases)")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--markdown", type=Path, default=None)
    parser.add_argument("--against", type=Path, default=None,
                        help="another finished suite of the same draws whose diagnoses are the changed ones (no "
                             "diagnosis is run; not with --set)")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    logging.getLogger("hybridfmu").setLevel(logging.WARNING)
    if args.against is not None and args.changes:
        raise SystemExit("--against compares two finished suites; it takes no --set")
    changes = [parse_change(text) for text in args.changes]
    config = load_case_config(args.config)
    withheld = args.withheld or ROOT / config.get("results_dir", "results") / "withheld"
    fmu = withheld.parent / config["case"] / "fmu" / f"{config['fmu']['model_name']}.fmu"  # the suite's own build
    section = config.get("withheld", {})
    calibration = section.get("calibration_seeds")
    if calibration is None:
        raise SystemExit(f"{args.config}: withheld.calibration_seeds is null; this script reads calibration seeds only")
    cases = sorted(p.name[:-len(".draw.json")] for p in (withheld / "cases").glob("*.draw.json"))
    cases = [c for c in cases if int(re.match(r"s(\d+)__", c).group(1)) in calibration
             and (args.cases is None or fnmatch.fnmatch(c, args.cases))]
    missing = [c for c in cases if not (withheld / c / "diagnosis" / "diagnosis.json").is_file()]
    if not cases or missing:
        raise SystemExit(f"{withheld}: no finished withheld suite ({len(missing)} of {len(cases)} calibration cases "
                         "without diagnosis.json); run `snakemake -j2 withheld` first")
    if args.against is not None:
        out, settings = args.against, against_suite(withheld, args.against, cases)
        arguments = "--withheld SUITE --against OTHER_SUITE"  # the two suites are named by their code above
    else:
        code = describe(code_version())
        slug = "__".join(re.sub(r"[^A-Za-z0-9_.=-]+", "_", text) for text in args.changes) or f"code-{code}"
        out, settings = args.out or withheld.with_name(withheld.name + "_settings") / slug, args.changes
        arguments = " ".join(f"--set {text}" for text in args.changes)
        jobs = [(c, withheld, fmu, out, changes) for c in cases]
        started = time.perf_counter()
        with multiprocessing.Pool(max(1, args.jobs)) as pool:
            for k, result in enumerate(pool.imap_unordered(_diagnose, jobs), start=1):
                elapsed = time.perf_counter() - started
                LOG.info("%d/%d cases (%s, %.0f s), %.2f cases/min, %.0f s left", k, len(jobs), result["case"],
                         result["seconds"], 60.0 * k / elapsed, elapsed / k * (len(jobs) - k))
    expected, background, targets = section.get("expected", {}), section.get("background", {}), section.get("targets")
    suite_records = {c: read_json(withheld / c / "diagnosis" / "diagnosis.json") for c in cases}
    # the code that made the changed diagnoses, as they record it (a case kept from an earlier run keeps its own)
    changed_code = ", ".join(code_versions({c: read_json(out / c / "diagnosis" / "diagnosis.json") for c in cases}))
    summary = {"n_cases": len(cases),
               "change": f"the code at {changed_code}" + "".join(f", `{text}`" for text in settings),
               "suite_code": ", ".join(code_versions(suite_records)), "changed_code": changed_code,
               "arguments": arguments,
               "suite": score(cases, {c: withheld / c / "diagnosis" / "diagnosis.json" for c in cases}, withheld,
                              expected, background, targets),
               "changed": score(cases, {c: out / c / "diagnosis" / "diagnosis.json" for c in cases}, withheld,
                                expected, background, targets)}
    text = markdown(summary)
    print(text)
    if args.markdown:
        write_text_atomic(args.markdown, text)
    print(json.dumps(summary, default=float))


if __name__ == "__main__":
    main()
