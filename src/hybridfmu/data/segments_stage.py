"""Rule select_segments: the informative spans of one ingested maneuver, written as JSON with their plot.

The selection itself is :func:`hybridfmu.data.segments.select_segments`; its figure (paper Fig. 8) is
:func:`hybridfmu.data.segments_plot.plot_segments`.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import pandas as pd

from hybridfmu.data.roles import CaseRoles, case_roles
from hybridfmu.data.errors import DataError
from hybridfmu.data.segments import SegmentSelection, segments_record, select_segments
from hybridfmu.data.segments_plot import plot_segments
from hybridfmu.io import write_json_atomic

LOG = logging.getLogger("hybridfmu.data.segments")


def select_segments_to_files(data_path: str | Path, json_path: str | Path, png_path: str | Path, maneuver: str,
                             config: dict[str, Any], roles: CaseRoles | None = None) -> SegmentSelection:
    """Select the segments of an ingested maneuver; write the JSON record and the Fig. 8 plot atomically.

    Args:
        data_path: the ingested maneuver (Parquet).
        json_path, png_path: outputs.
        maneuver: its name (record and title).
        config: the case config (sections ``segments`` and, unless ``roles`` is given, those
            :func:`hybridfmu.data.roles.case_roles` reads).
        roles: the case's roles, if already known.
    """
    roles = roles if roles is not None else case_roles(config)
    data_path = Path(data_path)
    try:
        frame = pd.read_parquet(data_path)
    except Exception as err:
        raise DataError(f"{data_path}: cannot read the ingested data: {err}") from None
    try:
        selection = select_segments(frame, roles, config.get("segments"))
    except DataError as err:
        raise DataError(f"{data_path}: {err}") from None
    LOG.info("%s: %d spans, %.1f%% of %.4g s kept", maneuver, len(selection.spans_s),
             100.0 * selection.fraction_kept, selection.duration_s)
    plot_segments(frame, selection, maneuver, png_path, roles)
    write_json_atomic(json_path, segments_record(maneuver, selection))
    return selection
