"""The diagnosed model saved for the stages after the diagnosis: the calibrated FMU plus the chosen effects.

The diagnosis' held-out check ends with one model, "FMU + effects": the chosen effects with their fitted
coefficients and settings and, when ``diagnosis.open_loop.refit`` is on, the model parameters recalibrated
together with them. :class:`DiagnosedModel` holds exactly that model; :func:`save_diagnosed` writes it
(``{results}/diagnosis/diagnosed_model.pkl``, a Python pickle of the package's own objects: read it with
the same version of the package) and :func:`load_diagnosed` reads it back. The evaluation simulates it
beside the FMU and the neural FMU, and a hybrid model (``model.physics_terms``) puts it under its ANN
(:mod:`hybridfmu.model.physics`).
"""

from __future__ import annotations

import contextlib
import pickle
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

from hybridfmu.diagnosis.corrected_model import CorrectedModel
from hybridfmu.diagnosis.problem import Problem
from hybridfmu.diagnosis.selection import Term
from hybridfmu.diagnosis.standstill_hold import StandstillHold
from hybridfmu.io import atomic_path

#: File name of the diagnosed model in the diagnosis folder.
DIAGNOSED_MODEL = "diagnosed_model.pkl"

#: Version of the saved layout; a file of another version is refused with a request to rerun the diagnosis.
FORMAT_VERSION = "diagnosed_model/3"


@dataclass
class DiagnosedModel:
    """The FMU plus the diagnosis' chosen effects.

    Attributes:
        terms: the chosen effects with fitted coefficients and settings, in rank order.
        parameters: model parameter -> value to set on the FMU on top of its calibrated parameters (the
            parameters recalibrated with the effects; {} without the refit).
        problem: the diagnosis problem (state and input names and counts, settings the terms read).
        effects: the effects' names, in rank order (for reports).
        initial_states: maneuver -> unmeasured state -> initial value recalibrated with the effects ({} without
            the refit; a maneuver not listed starts where the calibration says).
        hold: the standstill state held at rest by its friction (:mod:`hybridfmu.diagnosis.standstill_hold`), or
            None.
    """

    terms: list[Term]
    parameters: dict[str, float]
    problem: Problem
    effects: list[str] = field(default_factory=list)
    initial_states: dict[str, dict[str, float]] = field(default_factory=dict)
    hold: StandstillHold | None = None

    def initial_state(self, x0: np.ndarray, maneuver: str) -> np.ndarray:
        """``x0`` (n_x,) of ``maneuver`` with the unmeasured states recalibrated with the effects (a copy)."""
        out = np.array(x0, dtype=float)
        for name, value in (self.initial_states.get(maneuver) or {}).items():
            out[self.state_names.index(name)] = float(value)
        return out

    @property
    def state_names(self) -> list[str]:
        return list(self.problem.state_names)

    @property
    def input_names(self) -> list[str]:
        return list(self.problem.input_names)

    def selected(self, names: list[str] | None, without_kinds: tuple[str, ...] = ()) -> "DiagnosedModel":
        """The model with only the effects ``names`` (None: all), less those of the kinds ``without_kinds``.

        Raises:
            ValueError: a name that is not among the chosen effects (the message lists them).
        """
        if names is None and not without_kinds:
            return self
        unknown = [n for n in names or [] if n not in self.effects]
        if unknown:
            raise ValueError(f"config.model.physics_terms: {unknown} are not effects the diagnosis chose; "
                             f"expected some of {self.effects}")
        terms = [t for t in self.terms if (names is None or t.effect.name in names)
                 and t.effect.kind not in without_kinds]
        return DiagnosedModel(terms, dict(self.parameters), self.problem, [t.effect.name for t in terms],
                              {name: dict(values) for name, values in self.initial_states.items()}, self.hold)

    def simulate(self, fmu: Any, helper: Any, time_s: np.ndarray, u: np.ndarray, x0: np.ndarray) -> np.ndarray:
        """States (T, n_x) of the FMU plus the effects open loop from ``x0`` (n_x,) with the logged inputs ``u``
        (T, n_u) on the grid ``time_s`` (T,), as the diagnosis' held-out check simulates it (NaN rows after a
        failure). ``fmu`` and ``helper`` are two instances of the calibrated FMU; their parameters are restored."""
        with self.open_loop(fmu, helper) as simulate:
            return simulate(time_s, u, x0)

    @contextlib.contextmanager
    def open_loop(self, fmu: Any, helper: Any) -> Iterator[Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]]:
        """:meth:`simulate` for many calls (e.g. short windows): within the block, ``simulate(time_s (T,), u (T, n_u),
        x0 (n_x,)) -> states (T, n_x)`` gives :meth:`simulate`'s states bit for bit, the effects made and the
        parameters set once for all calls (each run initialises the FMU anew); restored when the block ends."""
        from hybridfmu.diagnosis.corrected_model import simulator_for
        from hybridfmu.diagnosis.refit import parameters_set, simulate_corrected

        corrected = self.corrected(helper) if self.terms else None
        with parameters_set([fmu, helper], self.parameters):
            with corrected.parameters_applied(fmu) if corrected is not None else contextlib.nullcontext():
                simulate_fn = simulator_for(fmu)

                def simulate(time_s: np.ndarray, u: np.ndarray, x0: np.ndarray) -> np.ndarray:
                    return simulate_corrected(fmu, simulate_fn, np.asarray(time_s, dtype=float),
                                              np.asarray(u, dtype=float), np.asarray(x0, dtype=float), corrected,
                                              apply_parameters=False)

                yield simulate

    def corrected(self, helper: Any) -> CorrectedModel:
        """The effects as changes of the model (:class:`CorrectedModel`); ``helper`` is a second model instance
        with ``parameters`` set, for effects that evaluate the model's derivatives."""
        return CorrectedModel(self.terms, self.problem, helper, hold=self.hold)


def save_diagnosed(model: DiagnosedModel, path: str | Path) -> Path:
    """Write ``model`` to ``path`` atomically (temporary file, then rename), readable as any file the user writes
    (the umask's mode, not a temporary file's owner-only 0600)."""
    path = Path(path)
    with atomic_path(path) as tmp, tmp.open("wb") as stream:
        pickle.dump({"format_version": FORMAT_VERSION, "model": model}, stream)
    return path


def load_diagnosed(path: str | Path) -> DiagnosedModel:
    """Read a model written by :func:`save_diagnosed`.

    Raises:
        FileNotFoundError: no such file (run the ``diagnose`` rule first).
        ValueError: a file that is not a diagnosed model of this format.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no diagnosed model; run the diagnosis first (snakemake rule diagnose)")
    try:
        with path.open("rb") as stream:
            content = pickle.load(stream)
    except (pickle.UnpicklingError, EOFError, AttributeError, ImportError) as err:
        raise ValueError(f"{path}: not a diagnosed model written by this package ({err}); rerun the diagnosis "
                         "(snakemake --forcerun diagnose)") from err
    if not isinstance(content, dict) or content.get("format_version") != FORMAT_VERSION \
            or not isinstance(content.get("model"), DiagnosedModel):
        found = content.get("format_version") if isinstance(content, dict) else type(content).__name__
        raise ValueError(f"{path}: field 'format_version' is {found!r}, expected {FORMAT_VERSION!r} with a "
                         "DiagnosedModel; rerun the diagnosis (snakemake --forcerun diagnose)")
    return content["model"]
