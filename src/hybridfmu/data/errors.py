"""The exception raised for bad measured data."""

from __future__ import annotations


class DataError(ValueError):
    """A raw log or an ingested frame cannot be used.

    The message names the file, the channel (or column) and what was expected there.
    """
