"""Messages <-> roger_attention core types."""

from __future__ import annotations

import math

from std_msgs.msg import Header

from roger_attention.controller import CycleRecord
from roger_attention.spatial_map import SpatialMap
from roger_common.conversions import point, seconds_to_time
from roger_common.types import RunCounters
from roger_interfaces.msg import MapEntry, Metrics, PolicyState
from roger_interfaces.msg import SpatialMap as SpatialMapMsg


def _header(stamp: float) -> Header:
    return Header(stamp=seconds_to_time(stamp), frame_id="roger_base")


def record_to_msg(record: CycleRecord, policy: str, stamp: float,
                  frame_stamp: float) -> PolicyState:
    """One completed cycle as a PolicyState message."""
    x0, y0, x1, y1 = record.bbox if record.bbox is not None else (0, 0, 0, 0)
    return PolicyState(
        header=_header(stamp), cycle=record.cycle, policy=policy,
        state_before=record.state_before, state_after=record.state_after,
        action=int(record.action), reward=float(record.reward),
        td_error=float("nan") if record.td_error is None else float(record.td_error),
        entry_id=int(record.entry_id),
        position=point(record.position if record.position is not None else (math.nan,) * 3),
        x0=int(x0), y0=int(y0), x1=int(x1), y1=int(y1), outcome=record.outcome,
        address=int(record.address), frame_stamp=seconds_to_time(frame_stamp))


def metrics_msg(counters: RunCounters, policy: str, map_entries: int, memory_size: int,
                done: bool, stamp: float) -> Metrics:
    """The run counters as a Metrics message."""
    c = counters
    return Metrics(header=_header(stamp), policy=policy, cycles=c.cycles,
                   attention_shifts=c.attention_shifts, improvements=c.improvements,
                   visual_improvements=c.visual_improvements,
                   haptic_improvements=c.haptic_improvements,
                   positive_identifications=c.positive_identifications,
                   new_objects=c.new_objects, map_updates=c.map_updates,
                   map_entries=map_entries, memory_size=memory_size, done=done)


def spatial_map_msg(spatial_map: SpatialMap, stamp: float, revision: int = 0) -> SpatialMapMsg:
    """The spatial map as a message (``revision``: rises with every map published)."""
    return SpatialMapMsg(header=_header(stamp), revision=int(revision), entries=[
        MapEntry(id=e.entry_id, position=point(e.position), mapped=e.mapped,
                 address=e.address, interest=float(e.interest),
                 activation=float(e.activation) if math.isfinite(e.activation) else 0.0)
        for e in spatial_map])
