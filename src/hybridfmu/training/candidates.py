"""The candidates of a search's final choice over whole maneuvers (config ``hpo.selection``), by name.

Light on purpose (no PyTorch): the workflow's rule files read it to name one ``score_finalist`` job per candidate.
"""

from __future__ import annotations

#: The trial id (and candidate name) of a hybrid search's physical layer among its finalists.
PHYSICAL_LAYER_ID = "physical_layer"


def finalist_candidate(rank: int) -> str:
    """``rank<k>``: the candidate name of the finalist with the ``rank``-th best objective (1: the best)."""
    return f"rank{rank}"


def candidate_names(top: int, physical_layer: bool) -> list[str]:
    """The candidates of a search's final choice, one job each: ``rank1`` .. ``rank<top>`` and, for a hybrid's
    search (``physical_layer``), :data:`PHYSICAL_LAYER_ID`."""
    return [finalist_candidate(k) for k in range(1, top + 1)] + ([PHYSICAL_LAYER_ID] if physical_layer else [])
