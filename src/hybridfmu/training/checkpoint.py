"""A trial's checkpoint file: its format, the fields it holds and its reader.

Written by a training job (:func:`hybridfmu.training.trial.run_trial_rung`, and the hybrid's physical layer by
:func:`hybridfmu.training.finalists.write_physical_layer_checkpoint`); read by the next rung, the final choice,
inference and the tracking of a search (a rung logged later). A module of its own so that each of them reads it
without importing the training job.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

#: Version of the checkpoint's layout.
CHECKPOINT_FORMAT = 1

#: Fields every trial checkpoint holds.
CHECKPOINT_FIELDS = ("format", "status", "bracket", "rung", "config", "spec", "model", "validations")


def load_checkpoint(path: str | Path) -> dict[str, Any]:
    """Read a trial checkpoint written by ``run_trial_rung``.

    Raises:
        FileNotFoundError: no such file.
        ValueError: the file is not a readable trial checkpoint (truncated, corrupt, another format); the
            message names the file and what was expected.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: checkpoint does not exist")
    try:
        checkpoint = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as err:  # torch raises OSError, RuntimeError, UnpicklingError ... for a damaged file
        raise ValueError(f"{path}: cannot read the checkpoint ({type(err).__name__}: {err}); expected a trial "
                         f"checkpoint (torch.save of a dict with format {CHECKPOINT_FORMAT}) written by "
                         f"run_trial_rung; delete it to retrain that rung") from None
    if not isinstance(checkpoint, dict) or checkpoint.get("format") != CHECKPOINT_FORMAT:
        found = checkpoint.get("format") if isinstance(checkpoint, dict) else type(checkpoint).__name__
        raise ValueError(f"{path}: not a trial checkpoint (field 'format' is {found!r}, expected {CHECKPOINT_FORMAT})")
    missing = [field for field in CHECKPOINT_FIELDS if field not in checkpoint]
    if missing:
        raise ValueError(f"{path}: trial checkpoint lacks the fields {missing} (expected {list(CHECKPOINT_FIELDS)})")
    return checkpoint
