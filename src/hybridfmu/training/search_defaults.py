"""The search's budget and window lengths chosen from the case's data where its config leaves them out.

A new case's maneuvers may last seconds or hours and be sampled at 10 kHz or 0.25 Hz, so the search's defaults
are relative to the data: ``hpo.max_resource_s`` (seconds of training data one configuration sees at most)
is :data:`RESOURCE_PER_TRAINING_DATA` times the selected training data, and a search space may give the
training window in grid samples (``window_samples``) instead of seconds (``window_s``). The plan records each
choice with its reason (``chosen_from_data``); a configured value always wins.
"""

from __future__ import annotations

from typing import Any

#: Without ``hpo.max_resource_s``: the most training data one configuration sees, in passes over the selected
#: segments of the training maneuver.
RESOURCE_PER_TRAINING_DATA = 10.0


def _in_seconds(entry: dict[str, Any], sample_period_s: float) -> dict[str, Any]:
    """A distribution over grid samples as the same distribution over seconds."""
    converted = dict(entry)
    for key in ("low", "high", "value"):
        if key in converted:
            converted[key] = float(converted[key]) * sample_period_s
    if "values" in converted:
        converted["values"] = [float(value) * sample_period_s for value in converted["values"]]
    return converted


def chosen_search_settings(hpo: dict[str, Any], sample_period_s: float | None,
                           training_data_s: float | None) -> tuple[dict[str, Any], list[str]]:
    """One search's settings (``hpo`` as :func:`hybridfmu.training.plan.search_settings` gives them) with what the
    config leaves to the data filled in, and a sentence per choice.

    Args:
        sample_period_s: the grid's step (s); converts a search space's ``window_samples`` into ``window_s``.
        training_data_s: duration (s) of the selected segments of the training maneuver; sizes a missing
            ``max_resource_s``.

    Raises:
        ValueError: a choice needs a figure of the data that was not given (names the field).
    """
    settings = dict(hpo)
    notes = []
    if settings.get("max_resource_s") is None:
        if not training_data_s:
            raise ValueError("config.hpo.max_resource_s is left to the data, but the selected training data's "
                             "duration is unknown; set config.hpo.max_resource_s")
        settings["max_resource_s"] = RESOURCE_PER_TRAINING_DATA * float(training_data_s)
        notes.append(f"hpo.max_resource_s = {settings['max_resource_s']:.4g} s: {RESOURCE_PER_TRAINING_DATA:g} passes "
                     f"over the {float(training_data_s):.4g} s of selected training data")
    space = dict(settings.get("search_space") or {})
    if "window_samples" in space:
        if sample_period_s is None:
            raise ValueError("config.hpo.search_space.window_samples needs the grid's sample period, which the plan "
                             "was not given")
        entry = _in_seconds(space.pop("window_samples"), float(sample_period_s))
        space["window_s"] = entry
        bounds = [entry[key] for key in ("low", "high", "value") if key in entry] or entry.get("values", [])
        notes.append(f"hpo.search_space.window_s: {entry['distribution']} over "
                     + ", ".join(f"{value:.4g}" for value in bounds)
                     + f" s (window_samples on the {float(sample_period_s):.4g} s grid)")
        settings["search_space"] = space
    return settings, notes
