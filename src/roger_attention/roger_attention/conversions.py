"""Messages <-> roger_attention core types: cycle reports, counters, the spatial map."""

from __future__ import annotations

import math
from collections.abc import Iterable

from geometry_msgs.msg import Pose, Quaternion, Vector3
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from roger_attention.controller import CycleRecord
from roger_attention.markers import MarkerShape, MarkerSpec
from roger_attention.session import PublishMap, PublishMetrics, Report
from roger_attention.spatial_map import MapEntry
from roger_common.conversions import header, point, seconds_to_time
from roger_common.frames import GROUND_FRAME
from roger_common.types import RunCounters
from roger_interfaces.msg import MapEntry as MapEntryMsg
from roger_interfaces.msg import Metrics, PolicyState
from roger_interfaces.msg import SpatialMap as SpatialMapMsg


def record_to_msg(record: CycleRecord, policy: str, stamp: float,
                  frame_stamp: float) -> PolicyState:
    """One completed cycle as a PolicyState message."""
    x0, y0, x1, y1 = record.bbox if record.bbox is not None else (0, 0, 0, 0)
    return PolicyState(
        header=header(stamp), cycle=record.cycle, policy=policy,
        state_before=record.state_before, state_after=record.state_after,
        action=int(record.action), reward=float(record.reward),
        td_error=float("nan") if record.td_error is None else float(record.td_error),
        entry_id=int(record.entry_id),
        position=point(record.position if record.position is not None else (math.nan,) * 3),
        x0=int(x0), y0=int(y0), x1=int(x1), y1=int(y1), outcome=record.outcome,
        address=int(record.address), frame_stamp=seconds_to_time(frame_stamp),
        goal_id=int(record.goal_id))


def report_to_msg(report: Report, policy: str) -> PolicyState:
    """A session's Report as a PolicyState message."""
    return record_to_msg(report.record, policy, report.stamp, report.frame_stamp)


def metrics_msg(counters: RunCounters, policy: str, map_entries: int, memory_size: int,
                done: bool, stamp: float, complete: bool = False) -> Metrics:
    """The run counters as a Metrics message."""
    c = counters
    return Metrics(header=header(stamp), policy=policy, cycles=c.cycles,
                   attention_shifts=c.attention_shifts, improvements=c.improvements,
                   visual_improvements=c.visual_improvements,
                   haptic_improvements=c.haptic_improvements,
                   positive_identifications=c.positive_identifications,
                   new_objects=c.new_objects, map_updates=c.map_updates, remaps=c.remaps,
                   map_entries=map_entries, memory_size=memory_size, done=done,
                   complete=complete)


def publish_metrics_to_msg(out: PublishMetrics, policy: str) -> Metrics:
    """A session's PublishMetrics as a Metrics message."""
    return metrics_msg(out.counters, policy, out.map_entries, out.memory_size, out.done,
                       out.stamp, out.complete)


def spatial_map_msg(entries: Iterable[MapEntry], stamp: float,
                    revision: int = 0) -> SpatialMapMsg:
    """Entries of the spatial map as a message (``revision``: rises with every map sent)."""
    return SpatialMapMsg(header=header(stamp), revision=int(revision), entries=[
        MapEntryMsg(id=e.entry_id, position=point(e.position), mapped=e.mapped,
                    address=e.address, interest=float(e.interest),
                    activation=float(e.activation) if math.isfinite(e.activation) else 0.0)
        for e in entries])


def publish_map_to_msg(out: PublishMap) -> SpatialMapMsg:
    """A session's PublishMap as a SpatialMap message."""
    return spatial_map_msg(out.entries, out.stamp, out.revision)


_MARKER_TYPES = {MarkerShape.SPHERE: Marker.SPHERE, MarkerShape.CYLINDER: Marker.CYLINDER,
                 MarkerShape.TEXT: Marker.TEXT_VIEW_FACING}


def markers_msg(specs: Iterable[MarkerSpec], stamp: float) -> MarkerArray:
    """The map's markers (roger_attention.markers) in the ground frame, after a DELETEALL
    that clears those of the previous map (entries that vanished go with them)."""
    head = header(stamp, GROUND_FRAME)
    out = [Marker(header=head, action=Marker.DELETEALL)]
    for s in specs:
        r, g, b, a = s.rgba
        out.append(Marker(
            header=head, ns=s.namespace, id=int(s.marker_id), type=_MARKER_TYPES[s.shape],
            action=Marker.ADD,
            pose=Pose(position=point(s.position), orientation=Quaternion(w=1.0)),
            scale=Vector3(x=float(s.scale[0]), y=float(s.scale[1]), z=float(s.scale[2])),
            color=ColorRGBA(r=float(r), g=float(g), b=float(b), a=float(a)), text=s.text))
    return MarkerArray(markers=out)
