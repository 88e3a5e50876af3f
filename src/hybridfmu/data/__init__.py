"""Measured data: raw-log readers, ingestion onto the case's grid, segment selection, FMU arrays.

Nothing here knows a particular machine: names, units and roles come from the case config
(:mod:`hybridfmu.data.roles`), units through :mod:`hybridfmu.units`.

- ``roles``: the case's signals, how they feed the FMU, which states are measured and compared, and each
  maneuver's raw source (``case_roles``, ``maneuver_source``).
- ``readers``: MDF4 / CSV / Parquet channels with their own time bases (``read_channels``).
- ``resample``: zero-order hold / linear interpolation onto a uniform grid, Savitzky-Golay filters.
- ``transforms``: derived signals a case declares (scale, derivative, park).
- ``ingest``: raw log -> the case's signals in model units -> Parquet (``ingest_log``, ``ingest_to_parquet``).
- ``segments`` / ``segments_plot``: spans that carry information (paper Sec. 2.3, Fig. 8).
- ``signals``: FMU input / measured-state / target arrays from an ingested frame, by the case's roles.
"""

from hybridfmu.data.errors import DataError

__all__ = ["DataError"]
