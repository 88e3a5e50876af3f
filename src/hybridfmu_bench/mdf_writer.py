"""Writing bench logs as MDF4 files, the way an ECU measurement tool records them.

Each channel group has its own time base (raster and start); channels carry names, units and
comments. Files are written atomically.
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from hybridfmu.io import atomic_path

#: Fixed recording start written into the header, so that equal inputs give equal files' content.
RECORDING_START = dt.datetime(2026, 1, 1, 8, 0, 0, tzinfo=dt.timezone.utc)


@dataclass
class Channel:
    """One logged channel: ``samples`` (shape (N,)) with its name, unit and comment."""

    name: str
    samples: np.ndarray
    unit: str
    comment: str


@dataclass
class ChannelGroup:
    """Channels sharing one time base ``timestamps_s`` (shape (N,), s)."""

    comment: str
    timestamps_s: np.ndarray
    channels: list[Channel] = field(default_factory=list)


def write_mdf4(path: str | Path, groups: Sequence[ChannelGroup], comment: str) -> Path:
    """Write ``groups`` to an MDF 4.10 file at ``path`` (atomically); return the path.

    Raises:
        ValueError: a channel's length differs from its group's time base, or a name repeats.
    """
    from asammdf import MDF, Signal

    seen: set[str] = set()
    mdf = MDF(version="4.10")
    mdf.header.start_time = RECORDING_START
    mdf.header.comment = comment
    try:
        for group in groups:
            timestamps = np.asarray(group.timestamps_s, dtype=np.float64)
            signals = []
            for channel in group.channels:
                samples = np.asarray(channel.samples)
                if samples.shape != timestamps.shape:
                    raise ValueError(f"{path}: channel {channel.name} has {samples.shape[0]} samples, its time base "
                                     f"has {timestamps.shape[0]}")
                if channel.name in seen:
                    raise ValueError(f"{path}: channel {channel.name} appears twice")
                seen.add(channel.name)
                signals.append(Signal(samples=samples, timestamps=timestamps, name=channel.name, unit=channel.unit,
                                      comment=channel.comment))
            mdf.append(signals, comment=group.comment)
        with atomic_path(path) as tmp:
            mdf.save(tmp, overwrite=True, compression=2)
    finally:
        mdf.close()
    return Path(path)
