"""The calibration stage's result: FMU parameter values and unmeasured initial states per maneuver.

Written by rule ``calibrate`` to ``{RESULTS}/calibration/calibration.json``; every later stage that
simulates the FMU (baseline, training, evaluation, diagnosis) loads the FMU with
``parameters`` and starts unmeasured states from :meth:`Calibration.unmeasured_initial_states`.

File format (JSON)::

    {"parameters": {name: value, ...},            # every parameter to set on the FMU (config + fitted)
     "fitted": [name, ...],                        # which of them the stage fitted
     "initial_states": {maneuver: {state: value}}, # unmeasured states at each maneuver's start
     "metrics": {...}}                             # fit quality (before/after), free form
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hybridfmu.io import read_json, write_json_atomic


@dataclass
class Calibration:
    """Calibrated FMU parameters and initial states (module docstring)."""

    parameters: dict[str, float] = field(default_factory=dict)
    fitted: list[str] = field(default_factory=list)
    initial_states: dict[str, dict[str, float]] = field(default_factory=dict)
    metrics: dict[str, Any] = field(default_factory=dict)

    def unmeasured_initial_states(self, maneuver: str, config: dict[str, Any],
                                  start_values: dict[str, float], unmeasured: list[str]) -> dict[str, float]:
        """Initial values of the unmeasured states for ``maneuver``.

        Order of precedence: the maneuver's own calibrated values; those of the maneuver named in
        ``config.maneuvers.<maneuver>.initial_states_from``; the FMU's start values (``start_values``).

        Args:
            maneuver: maneuver name.
            config: validated case config.
            start_values: FMU variable name -> start value (``ModelInterface.start_values``).
            unmeasured: names of the unmeasured states.

        Returns:
            state name -> initial value, for every state in ``unmeasured``.
        """
        source = config["maneuvers"].get(maneuver, {}).get("initial_states_from")
        own = self.initial_states.get(maneuver, {})
        other = self.initial_states.get(source, {}) if source else {}
        values = {}
        for name in unmeasured:
            if name in own:
                values[name] = float(own[name])
            elif name in other:
                values[name] = float(other[name])
            else:
                values[name] = float(start_values.get(name, 0.0))
        return values

    def to_dict(self) -> dict[str, Any]:
        return {"parameters": self.parameters, "fitted": self.fitted, "initial_states": self.initial_states,
                "metrics": self.metrics}

    def save(self, path: str | Path) -> Path:
        write_json_atomic(path, self.to_dict())
        return Path(path)

    @classmethod
    def load(cls, path: str | Path) -> "Calibration":
        """Read a calibration file.

        Raises:
            ValueError: the file lacks a field or holds a non-numeric value (names the file and field).
        """
        path = Path(path)
        record = read_json(path)
        if not isinstance(record, dict) or "parameters" not in record or "initial_states" not in record:
            raise ValueError(f"{path}: expected a calibration record with 'parameters' and 'initial_states'")
        try:
            parameters = {str(k): float(v) for k, v in record["parameters"].items()}
            states = {str(m): {str(k): float(v) for k, v in values.items()}
                      for m, values in record["initial_states"].items()}
        except (TypeError, ValueError, AttributeError) as err:
            raise ValueError(f"{path}: field 'parameters' or 'initial_states' is malformed: {err}") from None
        return cls(parameters, list(record.get("fitted", [])), states, dict(record.get("metrics", {})))
