"""Shape evidence beyond equations 1-5: the extended features (docs/perception.md,
"Extended features").

Equations 1-5 measure a silhouette's contrast, texture, stereo relief and area in the image;
a prism seen end-on and side-on gives other values, and a sphere and a cylinder of one grey
and weight give nearly the same. The extended mode adds measurements in the ground frame,
from what the robot knows of its own geometry (camera model and eye pose) and from touch:

Vision (every look; from the left retina's silhouette, the ROI's stereo position and the
known eye pose, never the simulator's objects):

* ``H``: height of the object's top. The ray through the silhouette's topmost pixel, in the
  column of the object's centre, passes over the vertical axis through the object's
  position (x, y) at a height ``z_over``: the top's height plus the part of the top that
  lies behind the axis, seen under the ray's declination. For a body that turns about the
  vertical (sphere, cylinder) nothing of it depends on yaw; for a box it grows by at most
  ``(sqrt 2 - 1) size / 2 tan(declination)`` between yaw 0 and 45 degrees.

* ``A``: the grey of the brightest surface the eye sees: the 90th percentile of the ROI's
  pixels in the left retina, each the mean of itself and its two neighbours along the row
  (the pixel noise over sqrt 3, so that a look of one exposure and one of several read
  alike). Along the row only: a far small box's top is a band of about three rows,
  whose 3 x 3 means mixed the sides above and below into every row but the middle one,
  so that the 90th percentile of them read a box at 1 m 0.011-0.019 darker than its
  copies at 0.6 m (docs/perception.md, "The brightest surface's grey"). Under the one
  directional light a surface's grey is its albedo times ``ambient + diffuse (n . l)``:
  it changes with the normal n, not with where the surface stands. The brightest
  surface of a box or a cylinder is its flat top (n up, the light from above), lit the
  same at every place and yaw, so copies of one flat-topped category read alike
  (boxes 77/77/77, 99/100/99, 106/107/107 in 255ths on yaw and random worlds 10021-10022)
  where the paper's rim contrast I, measured on the silhouette whose normals turn with
  the bearing, differs by 4-5 category scales. A sphere's and a prism's brightest
  visible surface turns with bearing and yaw (spheres 75-89, prisms 76-101), so A is
  view dependent for them: it never vetoes but between two flat tops (the memory's
  ``FLAT_VETO_FEATURES``).

* ``AS``: the albedo of a sphere: the silhouette's shading divided by what the known light
  (``PerceptionConfig.light_direction``, ``light_ambient``, ``light_diffuse``: the robot's
  knowledge of its light, as of its camera) gives a sphere's normals there
  (``sphere_albedo``). A sphere's brightest visible surface turns with the bearing, so its
  A does (one sphere of grey 100 read A 0.28-0.36 over bearings -60 to +60 degrees and
  0.5-1 m, sd 0.022; a Table-1 grey step is about 0.05), while its albedo does not: AS of
  the same looks 0.388-0.412 (sd 0.007; grey 100 is 0.392), and 2-2.5 % of the albedo at
  greys 60 and 180, sizes 0.06 and 0.14 m (docs/perception.md, "A sphere's albedo").
  Of a box, a cylinder or a prism the sphere's normals are wrong, and AS moves with the
  yaw and bearing (sd 0.015-0.03): the memory compares it only between two looks the hand
  found smooth and curved (``MemoryConfig.curved_veto``), where it vetoes.

* ``AP``: the albedo of a prism whose flanks the hand touched (``creased_albedo``; sight
  and touch together, unknown until a haptic improvement crossed a crease, TC >=
  ``AP_CREASE``, with a touch on a sloped face). A prism's brightest flank turns with its
  yaw against the one light, so A and the paper's I and T do (its copies' A 6-25 greys
  apart), and AS is no albedo of it (0.33-0.42 for grey 100). The touches on its flanks
  report their normals (tilt 55-64 degrees, azimuth the flank's, within 3-4 degrees; a
  touch near an end edge 20-30 degrees off, which the line of the touches along the ridge
  sets aside): they give both flanks' and both ends' normals, and under the known light
  each face's shading. Each silhouette pixel's grey over each face's shading is an albedo it may
  say; the one most pixels agree on is AP (faces weighted by how squarely the eye sees
  them). Prisms of greys 74, 100 and 103 alone at three places and five yaws each read
  0.280-0.301, 0.384-0.405 and 0.391-0.413 (sd 0.004-0.005; albedos 0.290, 0.392, 0.404),
  against AS's sd 0.018 and A's 0.023-0.047 (docs/perception.md, "A prism's albedo
  (AP)").

Three more visual measurements were built, measured and dropped (docs/perception.md,
"Extended features"): the silhouette's metric height over width (R), how far it reaches
above the top (E) and the median shading gradient (G). Between categories that differ only
in shape they moved as much as between copies of one category at other yaws (ratios 0.7-2.5
on the shape_twins and yaw_copies worlds 1001-1002), and in closed loop they stored prism
copies again.

Touch (after a haptic improvement, like W; from the tactile sensor's contact points and
normals of the first touch and its probe touches, ``HapticReading.contacts``):

* ``TH``: height of the highest contact point: the top's height, felt.
* ``TK``: the curvature the touches agree on. Between two contacts i, j the normal turns,
  along the chord between them, by ``(n_j - n_i) . (p_j - p_i) / |p_j - p_i|`` over
  ``|p_j - p_i|`` of surface (the discrete normal curvature in the chord's direction): on a
  sphere ``n = (p - c) / R``, so exactly 1 / radius for every pair, wherever the probes
  land; on a flat face 0. TK is the least-squares curvature over the *smooth* pairs
  (normals less than ``CREASE_RAD`` apart, at least ``MIN_PAIR_M`` apart):
  sum((n_j - n_i) . (p_j - p_i)) / sum(distance^2), which weighs the long pairs, whose
  normals' noise (0.03 rad each) matters least; clipped at 0 (no surface here is concave).
  A pair across an edge or a prism's ridge is no curvature. Times ``TK_SCALE_M``.

  Only the turn *along the chord* counts (2026-11-27; before, the whole turn
  ``|n_i - n_j|``): a touch on a prism's ridge or end edge reports a normal between two
  faces', less than a crease from its neighbour, and as a whole turn it read as a curve
  (a prism's pooled TK 0.04-0.41 over yaws, against 0.02-0.04 for boxes and cylinders).
  Such a normal mostly turns *across* the chord (the touches run along the ridge, the
  normal tips to one flank), which the along-chord turn ignores, and the noise of a flat
  face's normals, as likely across as along, averages to 0 instead of adding up. The
  simulator's own touches on one object at twelve yaws (five readings 1.5 cm apart,
  pooled; docs/perception.md, "TK along the chord"; bench/touch_yaw.py) read: prisms
  0.00-0.16 (size 0.10) and 0.00-0.08 (0.14), boxes and cylinders 0.00-0.01, a 12 cm
  sphere 0.49-0.50 (1 / R = 0.50), as before.

  TK is the curvature of a *smooth* surface: the least-squares curvature times 1 - TC
  (2026-11-28). Where the touches cross a crease (TC 1: a prism, whose touches always
  cross its ridge) the faces are flat, and what curvature the pairs still read is an
  edge's normal turning along the chord: single prism readings up to 0.43 in the robot's
  own looks, and with it TK's calibrated veto (the 99.9th percentile of one object's own
  repeats) was 1.26, beyond its range, so a sphere (TK 0.3-0.8) was taken for a box or
  cylinder (0.00-0.05) of its size and grey. A sphere's and a flat top's crease is near 0
  (0.05-0.15), so their TK is nearly unchanged. (docs/perception.md, "TK of a smooth
  surface".)
* ``TC``: the crease the touches cross: over the pairs, the largest angle between the
  normals that the curvature TK does not explain (``angle - curvature * distance``), over
  ``CREASE_FULL_RAD`` (45 degrees), clipped at 1. Of three probe directions 120 degrees
  apart one always crosses a prism's ridge, whatever the yaw: a flank's normal stands 60
  degrees from the ridge's (which the hand's flat face reports vertical) or 120 from the
  other flank's, depending on where the first touch landed. Over pi, as first built, that
  read 0.19-0.69 for copies of one prism (test/data/memory_queries_extended.csv.gz of
  2026-11-25 and the rows recorded on worlds 6001-6002): one object's crease split into
  two modes by the landing point. Every edge of a polyhedron in these worlds turns the
  normal by 60 degrees or more (a box's 90, a prism's 60 or 120), so a crease of 45
  degrees or more is "an edge crossed", whichever; a sphere's normals turn as its
  curvature says (0 but noise), a flat top's not at all.

Touches accumulate: ``touch_shape`` pools the last readings of one object
(``haptic.HapticMemory`` keeps them by position, as it keeps the weight): TK is the
least-squares curvature over the smooth pairs of all of them (pairs within one reading:
the object may have moved between two), TH and TC the median of the readings'. A second
haptic improvement on an object therefore adds its touches to the first's instead of
replacing them.

  Both replace ``TS`` (the steepest slope touched, 487cef8-bfe3283): on a sphere that was
  asin(offset / radius) where the probes landed, so copies of one sphere read 0.15-0.24
  and were stored again (docs/perception.md, "Extended features"). The drops of the probe
  contacts below the first were tried before TS: on a prism they depend on where the first
  touch landed beside the ridge, so they are not used either.

Each value is normalised to [0, 1] (clipped) by the constants below, like equations 4-5.
Pure numpy; no ROS.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence

import cv2
import numpy as np

from roger_common.geometry import camera_ray, project_point
from roger_common.types import CameraModel, EyePose, TactileContact

#: Pairs of touches closer than this (metres) give no curvature: their normals' noise
#: (0.03 rad each) over a short distance would read as a tight curve.
MIN_PAIR_M: float = 0.01
#: Two touches whose normals are this far apart (radians) lie across an edge or a ridge,
#: not on one smooth surface: a 10 cm sphere's touches 3 cm apart turn by 0.6.
CREASE_RAD: float = 0.9
#: A touch pressed an area (``pressed_area``) where a taxel this many taxels or more inside
#: the pad's border is pressed with all its neighbours.
AREA_INSET_TAXELS: int = 2
#: A crease of this many radians (or more) reads TC = 1: every edge of a box (90 degrees)
#: or a prism (60 or 120) is a full crease, wherever the first touch landed.
CREASE_FULL_RAD: float = math.pi / 4
#: TK is the curvature (1/m) times this: a sphere of 10-18 cm reads 0.6-0.33, and a radius
#: under 3 cm saturates at 1.
TK_SCALE_M: float = 0.03

#: A tactile image shows a ridge (``tactile_ridge``) when its pressed taxels form a line at
#: most this wide (metres; a prism's 60-degree flanks drop 3 mm, the skin's range, within
#: 2 mm of the ridge, so its line is 2-3 taxels wide)...
RIDGE_WIDTH_M: float = 0.006
#: ...and at least this long (metres)...
RIDGE_LENGTH_M: float = 0.015
#: ...with unpressed skin beyond it on both sides, all along it (this many taxels beyond
#: its last pressed taxel at least, and as many as half the line's length): a surface that
#: falls away on both sides, not the pad's own border resting on the edge of a flat top or
#: on a flank (pressed along one border of the pad only).
RIDGE_MARGIN_TAXELS: float = 0.5

#: A tactile image is a flat top pressed (``tactile_rim``) when its pressed taxels' depths
#: span at most this (metres, 5th to 95th percentile): the pad lies flat on it. A ridge's
#: or a sphere's depths span the skin's whole 3 mm.
FLAT_PRESS_M: float = 0.001
#: A rim is read from at least this many points of the pressed region's border inside the
#: pad...
RIM_MIN_TAXELS: int = 8
#: ...at least this long (metres): over a shorter piece a box's edge (its rim rounded
#: by a millimetre or two, the staircase of the 2 mm taxels) read up to 12 / m in closed
#: loop, where a 0.14 m cylinder's reads 14.
RIM_MIN_LENGTH_M: float = 0.03
#: A rim's parabola fits its border within this RMS (metres): a straight edge's or a
#: cylinder's rim within the staircase of 2 mm taxels (0.4-0.5 mm); a box's corner, two
#: straight edges at right angles, does not.
RIM_FIT_M: float = 0.0007
#: A box's corner under the pad (``_right_corner``): two straight edges whose directions
#: are a right angle apart within this (radians; a top's corner is 90 degrees exactly, the
#: 2 mm taxels' staircase turns a short edge's direction by a few degrees)...
CORNER_TOLERANCE_RAD: float = math.radians(15.0)
#: ...each at least this long (metres)...
CORNER_EDGE_M: float = 0.01
#: ...and holding all but this share of the border's points between them.
CORNER_OUTLIERS: float = 0.05
#: TR is the rim's curvature (1/m) times this: a cylinder of 0.06-0.14 m reads 0.67-0.29, a
#: straight edge 0.
TR_SCALE_M: float = 0.02

#: Heights are divided by this (metres): a 0.22 m box seen from 35-60 degrees above reads
#: z_over up to about 0.45 m (its far rim), so nothing saturates.
H_MAX_M: float = 0.5


def _ray(camera: CameraModel, pose: EyePose, u: float, v: float) -> np.ndarray:
    return np.asarray(camera_ray(camera, pose, u, v), float)


def height_over_axis(camera: CameraModel, pose: EyePose, u: float, v: float,
                     axis_xy: Sequence[float] | np.ndarray) -> float:
    """Height at which the ray through pixel (u, v) passes over a vertical axis at
    ``axis_xy`` (its point nearest that axis on the ground plane), metres."""
    o = np.asarray(pose.position, float)
    d = _ray(camera, pose, u, v)
    dh = d[:2]
    den = float(np.dot(dh, dh))
    if den <= 1e-12:
        return math.nan
    t = float(np.dot(np.asarray(axis_xy, float)[:2] - o[:2], dh) / den)
    return float(o[2] + t * d[2])


def top_height(mask: np.ndarray, bbox: tuple[int, int, int, int], camera: CameraModel,
               pose: EyePose, position: Sequence[float]) -> float:
    """``z_over`` of one ROI, metres, before normalisation (module docstring); NaN where
    not measurable.

    Args:
        mask: The ROI's silhouette inside ``bbox`` (left retina).
        bbox: (u0, v0, u1, v1) of the mask, u1/v1 exclusive.
        camera: The left retina's model.
        pose: The left eye's pose.
        position: The ROI's stereo position, robot frame (z up from the ground).
    """
    vs, us = np.nonzero(mask)
    if vs.size == 0:
        return math.nan
    us = us + bbox[0]
    vs = vs + bbox[1]
    p = np.asarray(position, float)
    # The topmost pixel of the columns within 1.5 px of the centre's column: its top edge
    # (v) is where the silhouette ends.
    cu = project_point(camera, pose, tuple(p))[0]
    near = np.abs(us + 0.5 - cu) <= 1.5
    if not near.any():
        near = np.ones_like(us, bool)
    top = float(vs[near].min())
    cols = np.unique(us[near])
    return float(np.median([height_over_axis(camera, pose, c + 0.5, top, p[:2])
                            for c in cols]))


def smoothed_grey(image: np.ndarray) -> np.ndarray:
    """Each pixel of the retina the mean of itself and its left and right neighbours
    (edges replicated): the image ``top_brightness`` reads, computed once per frame."""
    return cv2.blur(np.asarray(image, np.float32), (3, 1), borderType=cv2.BORDER_REPLICATE)


def top_brightness(smoothed: np.ndarray, mask: np.ndarray,
                   bbox: tuple[int, int, int, int]) -> float:
    """``A`` of one ROI in [0, 1] (module docstring); NaN for an empty mask.

    Args:
        smoothed: The left retina, intensities in [0, 1], through ``smoothed_grey``.
        mask: The ROI's silhouette inside ``bbox``.
        bbox: (u0, v0, u1, v1) of the mask, u1/v1 exclusive.
    """
    u0, v0, u1, v1 = bbox
    values = smoothed[v0:v1, u0:u1][mask.astype(bool)]
    if values.size == 0:
        return math.nan
    return _unit(float(np.percentile(values, 90)))


#: Pixels whose sphere normal is known well enough for ``sphere_albedo``: within this share
#: of the circle's radius of its centre (nearer the rim a pixel spans normals tens of
#: degrees apart, and a row's silhouette may end a pixel early or late).
SPHERE_CORE: float = 0.7


def sphere_albedo(image: np.ndarray, mask: np.ndarray, bbox: tuple[int, int, int, int],
                  rotation: np.ndarray, light: Sequence[float], ambient: float,
                  diffuse: float, ground: float) -> float:
    """``AS`` of one ROI in [0, 1] (module docstring); NaN where too little is seen.

    The silhouette is the ROI's pixels brighter than half-way from the ground's grey to
    the ROI's median (a ROI holds a rim of ground, 0-1 px, which would move the circle
    by a pixel: one sphere's AS then spread 6 % over four places against 1 % without
    it; a sphere's darkest pixel, its unlit side, is ``ambient`` over about
    ``ambient + diffuse / 2`` of its median, well above half-way). It is taken for a
    sphere's: a circle as wide as the silhouette whose top is the silhouette's top row
    (an object in front hides a sphere's bottom, never its top).
    Each pixel of its core (``SPHERE_CORE``) gets the sphere's normal there, in the camera
    frame (u, v, -sqrt(1 - u^2 - v^2)) over the radius (the eye sees the object under a
    few degrees, so the rays are taken parallel), turned into the robot frame by the eye's
    ``rotation``; its grey over ``ambient + diffuse max(0, n . l)`` is the albedo the pixel
    says, and AS is their mean (of a textured sphere the median is the light squares' or
    the dark ones', whichever more of the core shows: a checkered sphere's spread 0.21-0.37
    over 15 places, its mean 0.29-0.30; of a plain one the mean spreads as the median).

    Args:
        image: The left retina, intensities in [0, 1].
        mask: The ROI's silhouette inside ``bbox``.
        bbox: (u0, v0, u1, v1) of the mask, u1/v1 exclusive.
        rotation: The eye's camera axes in the robot frame (``EyePose.rotation``).
        light: Direction towards the light, robot frame (any length).
        ambient, diffuse: The Phong coefficients of the light.
        ground: The ground's grey in this retina (``segmentation.background_level``).
    """
    u0, v0, u1, v1 = bbox
    grey_box = np.asarray(image, float)[v0:v1, u0:u1]
    m = mask.astype(bool)
    if not m.any():
        return math.nan
    m &= grey_box > ground + 0.5 * (float(np.median(grey_box[m])) - ground)
    vs, us = np.nonzero(m)
    if vs.size == 0:
        return math.nan
    rho = 0.5 * float(us.max() - us.min() + 1)
    cu = 0.5 * float(us.min() + us.max() + 1)
    cv = float(vs.min()) + rho
    du = (us + 0.5 - cu) / rho
    dv = (vs + 0.5 - cv) / rho
    r2 = du * du + dv * dv
    core = r2 < SPHERE_CORE ** 2
    if int(core.sum()) < 3:
        return math.nan
    n_cam = np.stack([du[core], dv[core], -np.sqrt(1.0 - r2[core])], axis=1)
    normals = n_cam @ np.asarray(rotation, float).T
    shade = ambient + diffuse * np.clip(normals @ _unit_vector(light), 0.0, None)
    grey = grey_box[vs[core], us[core]]
    return _unit(float(np.mean(grey / shade)))


#: A touch whose normal stands this far from vertical or more (radians) and at most
#: ``SLOPE_MAX_RAD`` lay on a sloped face: a prism's flank (60 degrees, the simulator's
#: touches 55-64), never a flat top (0-5) nor a box's side (90); a sphere's probe touches
#: reach 25 degrees at most (a 5 cm sphere, 1.5 cm probes).
SLOPE_MIN_RAD: float = math.radians(30.0)
#: ...and at most this (radians).
SLOPE_MAX_RAD: float = math.radians(75.0)
#: ``creased_albedo`` is measured only where the touches' crease TC is at least this (a
#: ridge crossed; ``MemoryConfig.flat_crease``'s default).
AP_CREASE: float = 0.5
#: A face is seen where its normal turns this much or more towards the eye (cosine): a
#: face seen more edge-on is a sliver of a pixel or two.
FACE_SEEN: float = 0.05
#: Two pixels say one albedo where their albedos lie within this share of it: the pixel
#: noise (0.01) over a dark flank's grey (0.2), with the flanks' tilt as touched (3-4
#: degrees of noise: 1-2 % of the shading).
AP_TOLERANCE: float = 0.04
#: The ridge's line: touches whose normals stand within this of vertical (radians)...
RIDGE_TOP_RAD: float = math.radians(10.0)
#: ...within this of the highest touch (metres)...
RIDGE_TOP_M: float = 0.003
#: ...and at least this far apart (metres; closer, their direction is the taxels' noise:
#: the simulator's ridge touches 2-5 cm apart give the axis within 3-7 degrees, less
#: surely than two flanks that agree, so the line only arbitrates).
RIDGE_SPAN_M: float = 0.02
#: The sloped touches agree on the axis across the ridge within this (radians); where
#: they do not, the ridge line keeps those across it within this.
AP_AXIS_RAD: float = math.radians(10.0)
#: The vote's bins, in log albedo.
_AP_BIN: float = 0.005


def creased_albedo(image: np.ndarray, mask: np.ndarray, bbox: tuple[int, int, int, int],
                   readings: Sequence[Sequence[TactileContact]],
                   eye: Sequence[float] | np.ndarray, position: Sequence[float],
                   light: Sequence[float], ambient: float,
                   diffuse: float, ground: float) -> float:
    """``AP`` of one ROI in [0, 1] (module docstring): the albedo of a prism whose flanks
    the hand touched, NaN where no touch lay on a sloped face or too little is seen.

    The faces: the touches whose normals stand ``SLOPE_MIN_RAD``-``SLOPE_MAX_RAD`` from
    vertical lay on a flank. Their mean tilt and the axis of their azimuths (the mean of
    the doubled angles: the two flanks' azimuths are half a turn apart) give both flanks'
    normals (a prism's roof is symmetric), and the ends' are horizontal, along that axis's
    normal (the ridge). A face is seen where its normal turns towards the eye (more than
    ``FACE_SEEN``); under the known light it reads its albedo times
    ``ambient + diffuse max(0, n . l)``.

    Which pixel is which face is not needed: every silhouette pixel's grey over each seen
    face's shading is an albedo it may say, weighted by how squarely the eye sees that face
    (its share of the silhouette, for faces of about one area: a prism of size s has flanks
    of s x s / 2 and ends of 0.43 s^2). The albedo most pixels agree on (within
    ``AP_TOLERANCE``) wins: at the true albedo every face's pixels agree, at a wrong one
    only one face's. AP is the weighted median of the albedos within the tolerance of it.

    Args:
        image: The left retina, intensities in [0, 1].
        mask: The ROI's silhouette inside ``bbox``.
        bbox: (u0, v0, u1, v1) of the mask, u1/v1 exclusive.
        readings: The object's pooled touches (``HapticMemory.readings_near``).
        eye: The left eye's position, robot frame.
        position: The ROI's stereo position, robot frame.
        light: Direction towards the light, robot frame (any length).
        ambient, diffuse: The Phong coefficients of the light.
        ground: The ground's grey in this retina (``segmentation.background_level``).
    """
    pooled = [c for contacts in readings for c in contacts]
    if not pooled:
        return math.nan
    normals = np.stack([_unit_vector(c.normal) for c in pooled])
    tilt = np.arccos(np.clip(normals[:, 2], -1.0, 1.0))
    sloped = (tilt >= SLOPE_MIN_RAD) & (tilt <= SLOPE_MAX_RAD)
    if not sloped.any():
        return math.nan
    azimuth = np.arctan2(normals[sloped, 1], normals[sloped, 0])
    # The axis across the ridge: the sloped touches' azimuths (the mean of the doubled
    # angles: two flanks' are half a turn apart) where they agree within AP_AXIS_RAD. A
    # touch near an end edge reports a normal turned 20-30 degrees towards the end: where
    # they disagree, the line of the touches along the ridge (``_ridge_axis``) keeps the
    # ones across it, and without that line AP is unknown.
    kept = np.ones(len(azimuth), bool)
    axis = _axis_of(azimuth)
    if np.any(_turn(azimuth, axis) > AP_AXIS_RAD):
        ridge = _ridge_axis(pooled, tilt)
        if ridge is None:
            return math.nan
        kept = _turn(azimuth, ridge) <= AP_AXIS_RAD
        if not kept.any():
            return math.nan
        axis = _axis_of(azimuth[kept])
    t = float(np.mean(tilt[sloped][kept]))
    across = np.array([math.cos(axis), math.sin(axis), 0.0])
    along = np.array([-math.sin(axis), math.cos(axis), 0.0])
    up = np.array([0.0, 0.0, 1.0])
    faces = np.stack([math.sin(t) * across + math.cos(t) * up,
                      -math.sin(t) * across + math.cos(t) * up, along, -along])
    view = _unit_vector(np.asarray(eye, float) - np.asarray(position, float))
    seen = faces @ view
    faces, seen = faces[seen > FACE_SEEN], seen[seen > FACE_SEEN]
    if not len(faces):
        return math.nan
    shade = ambient + diffuse * np.clip(faces @ _unit_vector(light), 0.0, None)
    u0, v0, u1, v1 = bbox
    grey_box = np.asarray(image, float)[v0:v1, u0:u1]
    m = mask.astype(bool)
    if not m.any():
        return math.nan
    # The object's pixels: those on its side of half-way from the ground's grey to the
    # ROI's median (a ROI holds a rim of ground; a dark object lies below the ground).
    half = ground + 0.5 * (float(np.median(grey_box[m])) - ground)
    grey = grey_box[m & ((grey_box > half) if half >= ground else (grey_box < half))]
    grey = grey[grey > 0.0]
    if grey.size < 3:
        return math.nan
    albedo = (grey[:, None] / shade[None, :]).ravel()
    weight = np.broadcast_to(seen[None, :], (grey.size, len(seen))).ravel()
    log_a = np.log(albedo)
    lo = float(log_a.min()) - AP_TOLERANCE
    bins = int(math.ceil((float(log_a.max()) + AP_TOLERANCE - lo) / _AP_BIN)) + 1
    hist = np.bincount(((log_a - lo) / _AP_BIN).astype(int), weights=weight,
                       minlength=bins)
    width = 2 * int(round(AP_TOLERANCE / _AP_BIN)) + 1
    votes = np.convolve(hist, np.ones(width), mode="same")
    best = lo + (int(np.argmax(votes)) + 0.5) * _AP_BIN
    agree = np.abs(log_a - best) <= AP_TOLERANCE
    order = np.argsort(albedo[agree])
    cum = np.cumsum(weight[agree][order])
    return _unit(float(albedo[agree][order][int(np.searchsorted(cum, 0.5 * cum[-1]))]))


def _axis_of(azimuth: np.ndarray) -> float:
    """The axis (mod pi) of azimuths that may point either way along it: the mean of the
    doubled angles, halved (radians)."""
    return 0.5 * math.atan2(float(np.mean(np.sin(2.0 * azimuth))),
                            float(np.mean(np.cos(2.0 * azimuth))))


def _turn(azimuth: np.ndarray, axis: float) -> np.ndarray:
    """How far each azimuth lies from the axis, either way along it (radians, <= pi/2)."""
    return np.abs((azimuth - axis + math.pi / 2) % math.pi - math.pi / 2)


def _ridge_axis(contacts: Sequence[TactileContact], tilt: np.ndarray) -> float | None:
    """The horizontal direction across a ridge the touches ran along (radians), or None:
    the touches on top (normal within ``RIDGE_TOP_RAD`` of vertical, within
    ``RIDGE_TOP_M`` of the highest) whose farthest pair lies ``RIDGE_SPAN_M`` apart or more
    give the ridge's direction; across it is a quarter turn from that."""
    points = np.array([c.point for c in contacts], float)
    top = (tilt <= RIDGE_TOP_RAD) & (points[:, 2] >= points[:, 2].max() - RIDGE_TOP_M)
    xy = points[top, :2]
    if len(xy) < 2:
        return None
    d = np.linalg.norm(xy[:, None, :] - xy[None, :, :], axis=2)
    i, j = np.unravel_index(int(np.argmax(d)), d.shape)
    if d[i, j] < RIDGE_SPAN_M:
        return None
    along = xy[j] - xy[i]
    return math.atan2(float(along[1]), float(along[0])) + math.pi / 2


def visual_features(z_over: float) -> tuple[float]:
    """H normalised to [0, 1] (NaN stays NaN: unknown)."""
    return (_unit(z_over / H_MAX_M),)


def tactile_shape(contacts: Sequence[TactileContact]
                  ) -> tuple[float, float, float, float] | None:
    """TH, TK, TC and TR from one haptic improvement's touches, normalised to [0, 1].

    Args:
        contacts: The touches, first one first (``HapticReading.contacts``).

    Returns:
        (TH, TK, TC, TR), or None without a touch. With a single touch (or touches all
        closer than ``MIN_PAIR_M``) TK and TC are 0 (no pair shows a curve or a crease)
        unless its tactile image shows a ridge; TR is NaN where no tactile image shows a
        flat top's rim.
    """
    return touch_shape([contacts])


#: Touches whose tactile ridge and rim are kept (``tactile_ridge``, ``tactile_rim``): the
#: last readings' of a few dozen objects.
TOUCH_CACHE: int = 256


def touch_shape(readings: Sequence[Sequence[TactileContact]]
                ) -> tuple[float, float, float, float] | None:
    """TH, TK, TC and TR of one object from the touches of one or more haptic readings.

    Pairs of touches are formed within a reading only. TK is the least-squares curvature
    over the smooth pairs of every reading, times 1 - TC; TH and TC are the medians over
    the readings of each reading's top height and crease (the crease measured against the
    pooled curvature); TR the median of every rim the touches' tactile images show
    (``tactile_rim``), times ``TR_SCALE_M``, NaN without one.

    Args:
        readings: Each reading's touches (``HapticReading.contacts``); empty ones are
            skipped.

    Returns:
        (TH, TK, TC, TR) normalised to [0, 1] (TR NaN where unknown), or None when no
        reading has a touch.
    """
    readings = [r for r in readings if r]
    if not readings:
        return None
    tops, all_pairs = [], []
    for contacts in readings:
        tops.append(max(c.point[2] for c in contacts))
        points = [np.asarray(c.point, float) for c in contacts]
        normals = [_unit_vector(c.normal) for c in contacts]
        # (distance, turn along the chord times the distance, angle between the normals)
        pairs = [(float(np.linalg.norm(points[j] - points[i])),
                  float(np.dot(normals[j] - normals[i], points[j] - points[i])),
                  math.acos(max(-1.0, min(1.0, float(np.dot(normals[i], normals[j]))))))
                 for i in range(len(points)) for j in range(i + 1, len(points))]
        all_pairs.append([p for p in pairs if p[0] >= MIN_PAIR_M])
    smooth = [(dist, along) for pairs in all_pairs for dist, along, angle in pairs
              if angle < CREASE_RAD]
    curvature = (max(0.0, sum(a for _, a in smooth) / sum(d * d for d, _ in smooth))
                 if smooth else 0.0)
    creases = [max((max(0.0, angle - curvature * dist) for dist, _, angle in pairs),
                   default=0.0) for pairs in all_pairs]
    # A touch whose tactile image shows a ridge crossed a full crease under the pad itself.
    creases = [CREASE_FULL_RAD if any(tactile_ridge(c) for c in contacts) else crease
               for crease, contacts in zip(creases, readings, strict=True)]
    # A reading that found no full crease and whose tactile images never pressed an area
    # (every touch a line: the pad's border on an edge or a ridge) cannot tell a smooth
    # top from a ridge it never crossed: its crease is unknown.
    creases = [math.nan if crease < CREASE_FULL_RAD and _edges_only(contacts) else crease
               for crease, contacts in zip(creases, readings, strict=True)]
    known = [c for c in creases if math.isfinite(c)]
    crease = _unit(float(np.median(known)) / CREASE_FULL_RAD) if known else math.nan
    # The curvature of a smooth surface: where the touches cross a crease (TC 1) the faces
    # are flat and what the pairs read as a curve is an edge's normal (module docstring).
    smooth_share = 1.0 - crease if math.isfinite(crease) else 1.0
    rims = [r for contacts in readings for r in map(tactile_rim, contacts) if r is not None]
    rim = _unit(float(np.median(rims)) * TR_SCALE_M) if rims else math.nan
    return (_unit(float(np.median(tops)) / H_MAX_M),
            _unit(curvature * TK_SCALE_M * smooth_share), crease, rim)


def _edges_only(contacts: Sequence[TactileContact]) -> bool:
    """True when every touch has a tactile image and none of them pressed an area
    (``pressed_area``)."""
    return bool(contacts) and all(c.taxels >= 3 and c.pitch > 0.0 for c in contacts) \
        and not any(pressed_area(c) for c in contacts)


@functools.lru_cache(maxsize=TOUCH_CACHE)
def pressed_area(contact: TactileContact) -> bool:
    """True when the touch's tactile image pressed an area inside the pad: some pressed
    taxel with all eight neighbours pressed lies ``AREA_INSET_TAXELS`` or more from the
    pad's border (a flat top, a curved one, a flank under the pad); False for a line (an
    edge or a ridge under the pad or along its border), for a patch at the pad's border
    or corner (a ridge that only caught the pad's corner), and without an image."""
    n = contact.taxels
    if n < 3 or contact.pitch <= 0.0:
        return False
    pressed = np.isfinite(np.asarray(contact.image, float)).reshape(n, n).astype(np.uint8)
    core = cv2.erode(pressed, np.ones((3, 3), np.uint8), borderType=cv2.BORDER_CONSTANT,
                     borderValue=0) > 0
    k = AREA_INSET_TAXELS
    return bool(core[k:n - k, k:n - k].any())


@functools.lru_cache(maxsize=TOUCH_CACHE)
def tactile_ridge(contact: TactileContact) -> bool:
    """True when the touch's tactile image shows a ridge under the pad: the pressed taxels
    lie along a line (``RIDGE_WIDTH_M`` wide at most, ``RIDGE_LENGTH_M`` long at least)
    with unpressed skin on both sides of it all along (``RIDGE_MARGIN_TAXELS``).

    A flat top pressed over the pad reads an area; the pad's border resting on a top's edge
    or on a flank, a line along the border (one side only); a sphere, a disc 2.5 cm across
    or more (within the skin's 3 mm of its top). Only a prism's ridge, or the edge where
    two faces meet under the pad, reads a line with the surface falling away on both sides.
    False without an image.
    """
    n = contact.taxels
    if n < 3 or contact.pitch <= 0.0:
        return False
    pressed = np.isfinite(np.asarray(contact.image, float))
    if int(pressed.sum()) < 3:
        return False
    rows, cols = np.divmod(np.arange(n * n), n)
    xy = np.stack([cols, rows], axis=1) * contact.pitch
    centre = xy[pressed].mean(axis=0)
    _, axes = np.linalg.eigh(np.cov((xy[pressed] - centre).T))
    across, along = (xy - centre) @ axes[:, 0], (xy - centre) @ axes[:, 1]
    a_in, l_in = across[pressed], along[pressed]
    if np.ptp(a_in) > RIDGE_WIDTH_M or np.ptp(l_in) < RIDGE_LENGTH_M:
        return False
    beside = ~pressed & (along >= l_in.min()) & (along <= l_in.max())
    margin = RIDGE_MARGIN_TAXELS * contact.pitch
    need = 0.5 * np.ptp(l_in) / contact.pitch
    return bool(np.sum(beside & (across < a_in.min() - margin)) >= need
                and np.sum(beside & (across > a_in.max() + margin)) >= need)


@functools.lru_cache(maxsize=TOUCH_CACHE)
def tactile_rim(contact: TactileContact) -> float | None:
    """The curvature (1/m, unsigned) of a flat top's rim under the pad, from the touch's
    tactile image; None where the image shows no rim of a flat top.

    The pad lies flat on a top (the pressed taxels' depths within ``FLAT_PRESS_M``) and
    reaches over its rim: the pressed region's border inside the pad (the midpoints between
    a pressed taxel and an unpressed neighbour in its row or column; the pad's own border is
    not counted) is the rim, ``RIM_MIN_TAXELS`` points and ``RIM_MIN_LENGTH_M`` long at
    least. In the frame of its principal axes
    (u along it, v across) a parabola v = a + b u + c u^2 is fitted (least squares): the
    curvature is |2 c| (a circle of radius R reads 1 / R, a straight edge the noise of its
    staircase of taxels). A box's corner, two straight edges at a right angle
    (``_right_corner``: inside the pad, or beyond it with its edges cutting two of the
    pad's corners, the skin beyond then in two pieces), reads 0: a polygon's rim is
    straight wherever it runs. None for any other border the parabola does not follow
    within ``RIM_FIT_M`` RMS.

    Cached per contact (``TOUCH_CACHE``; a contact is frozen and the result a function of
    it alone): ``HapticMemory`` pools an object's last readings again whenever one is
    added, and the corner test costs milliseconds a touch.
    """
    n = contact.taxels
    if n < 3 or contact.pitch <= 0.0:
        return None
    depth = np.asarray(contact.image, float).reshape(n, n)
    pressed = np.isfinite(depth)
    if pressed.all() or int(pressed.sum()) < RIM_MIN_TAXELS:
        return None
    lo, hi = np.quantile(depth[pressed], [0.05, 0.95])
    if hi - lo > FLAT_PRESS_M:
        return None
    # One rim: the top and the skin beyond it each one piece (two pieces beyond: the pad
    # over a corner, its two edges cutting two of the pad's corners).
    pieces = [cv2.connectedComponents(part.astype(np.uint8), connectivity=4)[0] - 1
              for part in (pressed, ~pressed)]
    if pieces[0] != 1 or pieces[1] not in (1, 2):
        return None
    # The border: midway between each pressed taxel and an unpressed neighbour in its row
    # or column (the pad's own border is no rim).
    across_cols = np.nonzero(pressed[:, :-1] != pressed[:, 1:])
    across_rows = np.nonzero(pressed[:-1, :] != pressed[1:, :])
    rim = np.concatenate([
        np.stack([across_cols[1] + 0.5, across_cols[0]], axis=1),
        np.stack([across_rows[1], across_rows[0] + 0.5], axis=1)]) * contact.pitch
    if len(rim) < RIM_MIN_TAXELS:
        return None
    # A corner of a flat top: two straight edges at a right angle. Its rim is straight
    # wherever it runs (a polygon's), though no one parabola follows it.
    if _right_corner(rim, contact.pitch):
        return 0.0
    if pieces[1] != 1:
        return None  # the skin beyond in two pieces and no corner: no one rim
    centre = rim.mean(axis=0)
    _, _, axes = np.linalg.svd(rim - centre, full_matrices=False)
    u, v = (rim - centre) @ axes[0], (rim - centre) @ axes[1]
    if np.ptp(u) < RIM_MIN_LENGTH_M:
        return None
    coef = np.polyfit(u, v, 2)
    if float(np.sqrt(np.mean((np.polyval(coef, u) - v) ** 2))) > RIM_FIT_M:
        return None  # no one smooth curve, and no right corner either
    return float(abs(2.0 * coef[0]))


def _best_line(points: np.ndarray, band: float) -> tuple[np.ndarray, float]:
    """The straight line (angle of its normal every degree, offset anywhere) that holds the
    most of ``points`` within ``band`` of it: (inliers mask, normal's angle in radians)."""
    best, best_angle = np.zeros(len(points), bool), 0.0
    for angle in np.radians(np.arange(0.0, 180.0, 1.0)):
        proj = points @ np.array([math.cos(angle), math.sin(angle)])
        order = np.sort(proj)
        # For each point as the band's lower end, how many fall within 2 * band above it.
        counts = np.searchsorted(order, order + 2.0 * band, side="right") - np.arange(
            len(order))
        k = int(np.argmax(counts))
        if counts[k] > best.sum():
            best = (proj >= order[k] - 1e-12) & (proj <= order[k] + 2.0 * band + 1e-12)
            best_angle = float(angle)
    return best, best_angle


def _right_corner(rim: np.ndarray, pitch: float) -> bool:
    """True when the rim's points lie on two straight lines (within half a taxel) that meet
    at a right angle (within ``CORNER_TOLERANCE_RAD``), each at least ``CORNER_EDGE_M``
    long and together all but ``CORNER_OUTLIERS`` of the points: a box's corner under the
    pad (inside it, or beyond it with its two edges cutting two of the pad's corners). A
    cylinder's rim never turns a right angle within the 4 cm pad so straightly (a 3 cm
    radius sags 2.3 mm over a 45-degree arc)."""
    band = 0.5 * pitch
    first, a1 = _best_line(rim, band)
    rest = rim[~first]
    if len(rest) < 2:
        return False
    second, a2 = _best_line(rest, band)
    if (first.sum() + second.sum()) < (1.0 - CORNER_OUTLIERS) * len(rim):
        return False
    turn = abs((a1 - a2 + math.pi / 2) % math.pi - math.pi / 2)  # in [0, pi / 2]
    if abs(turn - math.pi / 2) > CORNER_TOLERANCE_RAD:
        return False
    for points, angle in ((rim[first], a1), (rest[second], a2)):
        along = points @ np.array([-math.sin(angle), math.cos(angle)])
        if len(points) < RIM_MIN_TAXELS // 2 or np.ptp(along) < CORNER_EDGE_M:
            return False
    return True


def _unit_vector(v: Sequence[float]) -> np.ndarray:
    a = np.asarray(v, float)
    n = float(np.linalg.norm(a))
    return a / n if n > 1e-12 else np.array([0.0, 0.0, 1.0])


def _unit(x: float) -> float:
    if not math.isfinite(x):
        return math.nan
    return float(min(1.0, max(0.0, x)))
