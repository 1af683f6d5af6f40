"""The fovea's shape evidence: O, how far an object's top outline departs from a cylinder's.

A box turned 45 degrees and a cylinder of one size, grey and weight differ, on Roger's 128 px
retinas, in a few pixels of their outline's corners (docs/perception.md, "Extended
features"). After a visual improvement the simulator also renders the centre of the left
eye's field at a higher resolution (``SimConfig.fovea_fov_deg``, ``fovea_size``: 30 degrees
at 192 px, 3.3 times the retina's resolution), as primate and iCub eyes have a fovea. On it:

1. **The top outline.** The ROI's silhouette (left retina) is mapped into the fovea (same
   pose and optical axis; only the focal length differs). In each of its columns the top
   edge is the strongest vertical intensity step within two retina pixels of the
   silhouette's top, to a tenth of a fovea pixel (a parabola through the peak). Columns
   whose step is under half the median step (a neighbour's edge, the ground) are dropped.
   The outline is the longest run of columns whose edge continues: no jump over
   ``MAX_STEP_PX`` a column, and across up to two retina pixels of dropped columns (a
   steep stretch, such as a box's edge that points at the eye, steps mostly across the
   columns) a slope within that which keeps the outline convex (``bridged``). It must
   cover ``WHOLE`` of the silhouette's width as the fovea shows it: the columns where a
   step near the top stands above the fovea's noise (the retina's silhouette can reach a
   retina pixel past the object over ground, a fifth of a small object's width).
2. **The cylinder hypothesis.** A vertical cylinder's top rim, seen from the eye, projects
   to an ellipse whose shape the known camera geometry gives: a horizontal circle around
   the ROI's stereo position, projected into the fovea and scaled to the outline's width.
   Its upper half is what the outline would be.
3. **O** is the outline's departure from that half-ellipse over the central 80 % of its
   width, after the best vertical shift: the RMS over the best ``TRIM`` of the columns
   (robust to a few columns of a neighbour's edge), over the ellipse's vertical
   half-axis, over ``O_MAX``. It counts up to the departure a straight edge across the
   same columns would have (the ellipse's own sag there): beyond it, how far an
   outline departs is how an edge's corners turn, which changes with the yaw.

A cylinder reads near 0 at any yaw and bearing (its outline is that ellipse; a sphere's is
close to it). A box's top outline is one straight edge (yaw 0) or two meeting at a corner
(yaw 45): against an ellipse of the same width both depart by a third of its height, at
any yaw, up to how the corner turns (0.15-0.38 over yaws before the departure was
capped at a straight edge's; 0.14-0.19 capped). A prism's outline is a triangle or a line
(read as a straight edge's departure or less). Invariant to position and bearing
(the ellipse comes from the eye's own pose), to grey and to distance (all in units of the
ellipse's own height); not to the silhouette's top being another object's (then unknown,
as H) nor to a top the fovea cuts (unknown).

Where more than 1 - ``WHOLE`` of a fixated ROI's top columns meet another ROI
(``top_against_other``: an object in line behind it, its bottom against this one's top),
the step found there may be between the two objects. Such a step adds departure (a
cylinder then reads like a box), it never takes a box's away: there the outline counts only
when it reads round, under ``ROUND`` of a straight edge's departure (``outline_feature``'s
``round_only``), and is unknown otherwise.

**The bottom outline.** Where the top's outline does not count (it meets another ROI and
does not read round, or is not seen whole), O is read from the silhouette's bottom edge,
where the object stands on the ground: the same steps with the edge searched near the
silhouette's lowest pixel in each column (``edge_outline(..., bottom=True)``), compared
with the near, lower half of the ellipse of a circle on the ground (z = 0) around the ROI's
stereo position. A cylinder's base is that circle; a box's bottom edge is one straight line
or two meeting at its near corner. In units of the ellipse's own height both read as the
top does (on twins, yaw and plain worlds 10031-10040: boxes 0.16-0.20 from the bottom,
0.16-0.19 from the top; cylinders 0.03-0.14 and 0.02-0.11), and an object standing in line
behind never meets the bottom. An object in front does: where more than 1 - ``WHOLE`` of
the bottom's columns meet another ROI below (``top_against_other(..., below=True)``), the
bottom does not count either. An outline partly hidden is no substitute: kept to 60 % of
its columns (the ellipse still placed by the whole width) 6 % of boxes read round, to 50 %
31 %.

``FoveaLooks`` keeps each measurement at its object's position, as ``HapticMemory`` keeps
the weight: O is known in every later frame that shows the object, unknown before the first
visual improvement onto it. Pure numpy/OpenCV; no ROS.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import numpy as np

from roger_common.types import CameraModel, EyePose
from roger_perception.haptic import nearest_within

#: O's departure (in units of the ellipse's vertical half-axis) is divided by this: boxes
#: read about 0.07-0.1 (0.14-0.19 as O), cylinders 0.01-0.035, no outline more than a straight
#: edge (``outline_departure``).
O_MAX: float = 0.5
#: Fewest outline columns O is measured from.
MIN_COLUMNS: int = 8
#: Share of the outline's half-width (either side of its middle) that O compares.
CENTRAL: float = 0.8
#: Largest jump of the top edge between neighbouring columns, fovea pixels, within one
#: outline (an ellipse's end, seen at Roger's declinations, climbs about 2.5 a column).
MAX_STEP_PX: float = 4.0
#: Slack of the convexity test across dropped columns (``bridged``), fovea rows a column.
CONVEX_SLACK: float = 1.0
#: An edge's step must be this many times the fovea's noise (its median step).
EDGE_SNR: float = 4.0
#: Share of the silhouette's width the top outline must cover (else O is unknown).
WHOLE: float = 0.75
#: Share of the central columns whose departure O averages (the rest may be a neighbour's).
TRIM: float = 0.9
#: Where a fixated ROI's top meets another ROI, its outline counts only when it departs
#: from the half-ellipse by less than this share of a straight edge's departure: a step
#: found between two objects adds departure (a cylinder read like a box), it never takes
#: a box's away (module docstring).
ROUND: float = 0.5
#: The fixated ROI's silhouette reaches this close to the optical axis, retina pixels.
FIXATION_PX: float = 3.0
#: Radius of the circle projected for the ellipse's shape, metres (only its shape counts).
_R0 = 0.05


def fovea_steps(fovea: np.ndarray) -> tuple[np.ndarray, float]:
    """The smoothed fovea's vertical steps (``step[v]``: between rows v and v + 1) and the
    floor an edge's step must exceed: most of the fovea is flat, so its median step is the
    image's own noise, and an edge must stand EDGE_SNR times above it."""
    img = cv2.GaussianBlur(np.asarray(fovea, np.float32), (0, 0), 1.0)
    step = np.abs(np.diff(img, axis=0))
    return step, max(EDGE_SNR * 1.4826 * float(np.median(step)), 1e-4)


def top_outline(fovea: np.ndarray, fovea_camera: CameraModel, camera: CameraModel,
                mask: np.ndarray, bbox: tuple[int, int, int, int],
                steps: tuple[np.ndarray, float] | None = None,
                ) -> tuple[np.ndarray, np.ndarray] | None:
    """The top edge of a ROI's silhouette, refined on the fovea (module docstring, step 1):
    ``edge_outline`` of the top."""
    return edge_outline(fovea, fovea_camera, camera, mask, bbox, steps)


def silhouette_in_fovea(mask: np.ndarray, bbox: tuple[int, int, int, int],
                        camera: CameraModel, fovea_camera: CameraModel, margin: float
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """A ROI's left-retina silhouette mapped into the fovea (same pose and optical axis;
    only the focal length differs), and for every fovea column and row its retina column
    and row.

    Args:
        mask, bbox: The silhouette inside ``bbox`` (u0, v0, u1, v1; u1/v1 exclusive).
        margin: The box must lie this many fovea pixels inside the fovea's border.

    Returns:
        (sil, ui, vi): sil (Hf, Wf) bool; ui, vi the retina column of each fovea column and
        the retina row of each fovea row, relative to ``bbox`` (may fall outside it). None
        when the box is not wholly inside the fovea, ``margin`` off its border.
    """
    m = fovea_camera.focal_px / camera.focal_px
    hf, wf = fovea_camera.height, fovea_camera.width
    uf0 = (bbox[0] - camera.width / 2.0) * m + wf / 2.0
    uf1 = (bbox[2] - camera.width / 2.0) * m + wf / 2.0
    vf0 = (bbox[1] - camera.height / 2.0) * m + hf / 2.0
    vf1 = (bbox[3] - camera.height / 2.0) * m + hf / 2.0
    if uf0 < margin or vf0 < margin or uf1 > wf - margin or vf1 > hf - margin:
        return None
    uc = (np.arange(wf) + 0.5 - wf / 2.0) / m + camera.width / 2.0
    vc = (np.arange(hf) + 0.5 - hf / 2.0) / m + camera.height / 2.0
    ui, vi = np.floor(uc).astype(int) - bbox[0], np.floor(vc).astype(int) - bbox[1]
    in_u = (ui >= 0) & (ui < mask.shape[1])
    in_v = (vi >= 0) & (vi < mask.shape[0])
    sil = np.zeros((hf, wf), bool)
    sil[np.ix_(in_v, in_u)] = mask[np.ix_(vi[in_v], ui[in_u])]
    return sil, ui, vi


def edge_outline(fovea: np.ndarray, fovea_camera: CameraModel, camera: CameraModel,
                 mask: np.ndarray, bbox: tuple[int, int, int, int],
                 steps: tuple[np.ndarray, float] | None = None, bottom: bool = False,
                 ) -> tuple[np.ndarray, np.ndarray] | None:
    """The top edge of a ROI's silhouette, or with ``bottom`` its bottom edge (where it
    stands on the ground), refined on the fovea (module docstring, step 1).

    Args:
        fovea: The foveal image, float (Hf, Wf).
        fovea_camera: Its intrinsics.
        camera: The left retina's intrinsics (same pose and optical axis).
        mask: The ROI's silhouette inside ``bbox`` (left retina).
        bbox: (u0, v0, u1, v1) of the mask, u1/v1 exclusive.
        steps: ``fovea_steps(fovea)``, when already computed for this fovea.
        bottom: The bottom edge instead of the top.

    Returns:
        (columns, rows): fovea columns and the edge's row in each (fovea pixels, edges at
        integers); None when the silhouette is not wholly inside the fovea or too few
        columns show a clear edge.
    """
    m = fovea_camera.focal_px / camera.focal_px
    mapped = silhouette_in_fovea(mask, bbox, camera, fovea_camera, margin=1.0)
    if mapped is None:
        return None
    sil = mapped[0]
    hf = sil.shape[0]
    if not sil.any():
        return None
    cols = np.flatnonzero(sil.any(axis=0))
    step, floor = fovea_steps(fovea) if steps is None else steps
    reach = max(2, int(round(2 * m)))
    tops, strength = [], []
    for c in cols:
        rows = np.flatnonzero(sil[:, c])
        v_edge = int(rows[-1]) if bottom else int(rows[0])
        lo, hi = max(0, v_edge - reach), min(hf - 1, v_edge + reach)
        seg = step[lo:hi, c]
        k = int(np.argmax(seg))
        off = 0.0
        if 0 < k < len(seg) - 1:
            den = float(seg[k - 1] - 2.0 * seg[k] + seg[k + 1])
            off = 0.5 * float(seg[k - 1] - seg[k + 1]) / den if den != 0.0 else 0.0
        tops.append(lo + k + 1 + off)
        strength.append(float(seg[k]))
    s = np.asarray(strength)
    # The silhouette's width, as the fovea shows it: the retina's silhouette can reach a
    # retina pixel (``m`` fovea columns) past the object on either side, over ground, where
    # no step near its top stands above the fovea's noise.
    seen = np.flatnonzero(s > floor)
    if seen.size == 0:
        return None
    span = cols[seen[-1]] + 1 - cols[seen[0]]
    keep = (s >= 0.5 * float(np.median(s))) & (s > floor)
    cols, top = cols[keep], np.asarray(tops)[keep]
    if cols.size < MIN_COLUMNS:
        return None
    # The longest run of columns whose edge continues (a merged neighbour's outline, or a
    # stretch of ground edge, breaks it). Where the outline is steep, as at a box's corner
    # whose edge points at the eye, its step is mostly across the columns, and those columns
    # fall under the strength test: the run continues over them (``bridged``).
    # A bottom edge turns the other way in image rows: mirrored, it is a top's.
    breaks = np.flatnonzero(~bridged(cols, -top if bottom else top, reach)) + 1
    runs = np.split(np.arange(cols.size), breaks)
    run = max(runs, key=len)
    # The outline must be seen whole: against a neighbour of its own grey, or behind
    # one, only a stretch of it shows, and a stretch of an ellipse is no ellipse.
    if run.size < MIN_COLUMNS or cols[run[-1]] + 1 - cols[run[0]] < WHOLE * span:
        return None
    return cols[run], top[run]


def bridged(cols: np.ndarray, top: np.ndarray, reach: int) -> np.ndarray:
    """For each pair of neighbouring kept columns, whether the outline continues between
    them (``top_outline``'s run).

    Next to each other (at most 2 fovea columns apart) it continues when the edge jumps
    at most ``MAX_STEP_PX``. Across columns the strength test dropped (up to ``reach``, two
    retina pixels) it continues when the edge's slope across them is at most
    ``MAX_STEP_PX`` a column and keeps the outline convex: every shape is convex, so its
    silhouette's top edge turns one way (in image rows, the slope never decreases from left
    to right). The slope across the gap must lie between the slopes of the kept columns
    just before and just after it, within ``CONVEX_SLACK``. A neighbour's top met at the
    outline's end, lower and flatter, turns the other way.
    """
    gap = np.diff(cols)
    rise = np.diff(top)
    ok = (gap <= 2) & (np.abs(rise) <= MAX_STEP_PX)
    for i in np.flatnonzero((gap > 2) & (gap <= reach)):
        slope = rise[i] / gap[i]
        if abs(slope) > MAX_STEP_PX:
            continue
        lo = i
        while lo > 0 and i - lo < 3 and gap[lo - 1] <= 2:
            lo -= 1
        hi = i + 1
        while hi < cols.size - 1 and hi - (i + 1) < 3 and gap[hi] <= 2:
            hi += 1
        before = (top[i] - top[lo]) / (cols[i] - cols[lo]) if lo < i else -math.inf
        after = (top[hi] - top[i + 1]) / (cols[hi] - cols[i + 1]) if hi > i + 1 else math.inf
        ok[i] = before - CONVEX_SLACK <= slope <= after + CONVEX_SLACK
    return ok


def outline_departure(columns: np.ndarray, tops: np.ndarray, fovea_camera: CameraModel,
                      pose: EyePose, position: Sequence[float], bottom: bool = False) -> float:
    """O before normalisation (module docstring, steps 2-3); NaN where not measurable.

    Args:
        columns, tops: ``edge_outline``'s result.
        fovea_camera: The fovea's intrinsics.
        pose: The left eye's pose (the fovea's).
        position: The ROI's stereo position, robot frame.
        bottom: The outline is the bottom edge: compared with the near (lower) half of the
            ellipse of a circle on the ground, where the object stands.
    """
    own, straight = outline_departures(columns, tops, fovea_camera, pose, position, bottom)
    return min(own, straight)


def outline_departures(columns: np.ndarray, tops: np.ndarray, fovea_camera: CameraModel,
                       pose: EyePose, position: Sequence[float], bottom: bool = False,
                       ) -> tuple[float, float]:
    """The outline's own departure from the half-ellipse and a straight edge's across the
    same columns, both in units of the ellipse's vertical half-axis (``outline_departure``
    is the smaller); (NaN, NaN) where not measurable. Arguments as
    ``outline_departure``'s."""
    p = np.asarray(position, float)
    angles = np.linspace(0.0, 2.0 * math.pi, 181)[:-1]
    rim = np.column_stack([p[0] + _R0 * np.cos(angles), p[1] + _R0 * np.sin(angles),
                           np.full(angles.size, 0.0 if bottom else p[2])])
    # project_point for every rim point at once (pinhole, pixel centres at +0.5).
    cam = (rim - np.asarray(pose.position, float)) @ np.asarray(pose.rotation, float)
    if not np.all(cam[:, 2] > 1e-9):
        return math.nan, math.nan
    pu = fovea_camera.focal_px * cam[:, 0] / cam[:, 2] + fovea_camera.width / 2.0
    pv = fovea_camera.focal_px * cam[:, 1] / cam[:, 2] + fovea_camera.height / 2.0
    width = (pu.max() - pu.min()) / 2.0
    half = (columns.max() + 1 - columns.min()) / 2.0
    if width <= 0 or half < MIN_COLUMNS / 2:
        return math.nan, math.nan
    scale = half / width
    pu = (pu - (pu.max() + pu.min()) / 2.0) * scale
    pv = pv * scale
    sag = (pv.max() - pv.min()) / 2.0
    x = columns + 0.5 - (columns.min() + columns.max() + 1) / 2.0
    # The ellipse's upper envelope at each column: the smallest v of the polygon's edges
    # that span it (the lower one, the largest v, for a bottom edge).
    u1, v1 = pu, pv
    u2, v2 = np.roll(pu, -1), np.roll(pv, -1)
    lo, hi = np.minimum(u1, u2), np.maximum(u1, u2)
    span = (x[:, None] >= lo[None]) & (x[:, None] <= hi[None]) & (hi > lo)[None]
    with np.errstate(divide="ignore", invalid="ignore"):
        v_at = v1[None] + (x[:, None] - u1[None]) * (v2 - v1)[None] / (u2 - u1)[None]
    if bottom:
        envelope = np.where(span, v_at, -np.inf).max(axis=1)
    else:
        envelope = np.where(span, v_at, np.inf).min(axis=1)
    ok = np.isfinite(envelope) & (np.abs(x) <= CENTRAL * half)
    if ok.sum() < MIN_COLUMNS // 2 or sag <= 0:
        return math.nan, math.nan
    # Beyond a straight edge's departure (a level row across the same columns), how far
    # an outline departs says nothing more of a round top: it is how an edge's corners
    # turn, which changes with the yaw (a box read 0.15-0.38 as O over yaws, a cylinder
    # 0.02-0.07). O counts the departure up to that of a straight edge.
    return (float(_departure(tops[ok] - envelope[ok]) / sag),
            float(_departure(-envelope[ok]) / sag))


def _departure(d: np.ndarray) -> float:
    """RMS of an outline's deviations from the ellipse after the best vertical shift
    (their median), over the columns that agree best (TRIM of them): a few columns of
    another edge do not count, a straight edge's departure at both ends does."""
    d = d - np.median(d)
    a = np.sort(np.abs(d))[:max(1, int(round(TRIM * d.size)))]
    return float(np.sqrt(np.mean(a ** 2)))


def outline_feature(fovea: np.ndarray, fovea_camera: CameraModel, camera: CameraModel,
                    pose: EyePose, mask: np.ndarray, bbox: tuple[int, int, int, int],
                    position: Sequence[float],
                    steps: tuple[np.ndarray, float] | None = None,
                    round_only: bool = False, bottom_free: bool = False) -> float:
    """O of one ROI normalised to [0, 1]; NaN where the fovea does not measure it
    (``steps``: as for ``top_outline``). ``round_only``: the top's outline counts only
    where it departs less than ``ROUND`` of a straight edge's departure (a top that meets
    another ROI: module docstring). ``bottom_free``: where the top's outline does not
    count, the bottom's does (module docstring, "The bottom outline"): the silhouette's
    bottom meets the ground, no other ROI."""
    outline = top_outline(fovea, fovea_camera, camera, mask, bbox, steps)
    if outline is not None:
        own, straight = outline_departures(*outline, fovea_camera, pose, position)
        dep = min(own, straight)
        if math.isfinite(dep) and not (round_only and not own < ROUND * straight):
            return float(min(1.0, dep / O_MAX))
    if not bottom_free:
        return math.nan
    outline = edge_outline(fovea, fovea_camera, camera, mask, bbox, steps, bottom=True)
    if outline is None:
        return math.nan
    dep = outline_departure(*outline, fovea_camera, pose, position, bottom=True)
    return float(min(1.0, dep / O_MAX)) if math.isfinite(dep) else math.nan


def fixated(mask: np.ndarray, bbox: tuple[int, int, int, int], camera: CameraModel,
            reach_px: float = FIXATION_PX) -> bool:
    """True when the ROI's silhouette reaches within ``reach_px`` retina pixels of the
    optical axis: the object the eye fixates, the one a visual improvement looks at. Only
    its O is measured: another object at the fovea's side is seen in passing, often cut or
    merged with its neighbour."""
    vs, us = np.nonzero(mask)
    if vs.size == 0:
        return False
    du = us + bbox[0] + 0.5 - camera.width / 2.0
    dv = vs + bbox[1] + 0.5 - camera.height / 2.0
    return bool(np.min(du * du + dv * dv) <= reach_px * reach_px)


def top_against_other(mask: np.ndarray, bbox: tuple[int, int, int, int],
                      labels: np.ndarray, own: int, reach_px: int = 2,
                      below: bool = False) -> float:
    """Share of a ROI's silhouette columns whose top borders another ROI: within
    ``reach_px`` retina pixels above the column's topmost pixel lies another ROI's pixel.
    There the outline's edge is a step between two objects, not the object's own edge
    against the ground (an object standing in line behind it, its bottom meeting this
    one's top), and O would measure the two together. With ``below``, the share whose
    bottom borders another ROI below the column's lowest pixel (an object in line in front
    of it, its top meeting this one's bottom).

    Args:
        mask: The ROI's silhouette inside ``bbox`` (left retina).
        bbox: (u0, v0, u1, v1) of the mask in the image.
        labels: The frame's ROI label image (0 ground, ``own`` this ROI).
        own: This ROI's label.
        reach_px: How far above the top (below the bottom) to look.
        below: Below the bottom instead of above the top.
    """
    cols = np.flatnonzero(mask.any(axis=0))
    if cols.size == 0:
        return 0.0
    if below:
        edges = mask.shape[0] - 1 - np.argmax(mask[::-1, cols], axis=0) + bbox[1]
    else:
        edges = np.argmax(mask[:, cols], axis=0) + bbox[1]
    u = cols + bbox[0]
    hit = np.zeros(cols.size, bool)
    for k in range(1, reach_px + 1):
        v = edges + k if below else edges - k
        inside = (v >= 0) & (v < labels.shape[0])
        lab = np.where(inside, labels[np.clip(v, 0, labels.shape[0] - 1), u], 0)
        hit |= inside & (lab != 0) & (lab != own)
    return float(hit.mean())


class FoveaLooks:
    """O of the objects a visual improvement looked at, by position (module docstring):
    the median of an object's last ``keep`` measurements, so that one look at a moment
    its outline was half hidden does not decide.

    Args:
        radius: A measurement belongs to a later ROI within this distance (ground plane),
            metres.
    """

    def __init__(self, radius: float, keep: int = 5) -> None:
        self.radius = float(radius)
        self.keep = int(keep)
        self._positions: list[np.ndarray] = []
        self._values: list[list[float]] = []

    def add(self, position: Sequence[float], value: float) -> None:
        """Add ``value`` to the object at ``position`` (a new object when none is near)."""
        pos = np.asarray(position, float)
        i = self._nearest(pos)
        if i is None:
            self._positions.append(pos)
            self._values.append([float(value)])
        else:
            self._positions[i] = pos
            self._values[i] = (self._values[i] + [float(value)])[-self.keep:]

    def near(self, position: Sequence[float]) -> float | None:
        """O of the nearest object within the radius (its looks' median), or None."""
        i = self._nearest(np.asarray(position, float))
        return None if i is None else float(np.median(self._values[i]))

    def clear(self) -> None:
        """Forget every measurement."""
        self._positions.clear()
        self._values.clear()

    def _nearest(self, pos: np.ndarray) -> int | None:
        return nearest_within(self._positions, pos, self.radius)
