"""Measured data: raw-log readers, ingestion onto the case's grid, segment selection, FMU arrays.

- ``readers``: MDF4 / CSV / Parquet channels with their own time bases (``read_channels``).
- ``units``: unit strings of ECU logs -> SI scale factors.
- ``channels``: the case's channel map (canonical signal -> raw channel, unit, column).
- ``resample``: zero-order hold / linear interpolation onto a uniform grid.
- ``ingest``: raw log -> canonical DataFrame -> Parquet (``ingest_log``, ``ingest_to_parquet``).
- ``segments`` / ``segments_plot``: spans that carry information (paper Sec. 2.3, Fig. 8).
- ``signals``: FMU input/state arrays from an ingested frame (incl. i_d, i_q via Park).
"""

from hybridfmu.data.errors import DataError

__all__ = ["DataError"]
