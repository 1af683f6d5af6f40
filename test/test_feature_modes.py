"""The two feature modes: the paper's eleven features stay what they were, bit for bit, and
the extended mode appends the shape evidence (docs/perception.md, "Extended features").

test/data/paper_features.npz holds eight stereo frames of worlds/shapes.yaml (simulator seed
3: an attention shift and a haptic improvement on each of four objects) and the eleven
features of every ROI of them as perception computed them before the modes existed (commit
487cef8, run on these frames).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from roger_common.types import (
    FEATURE_NAMES,
    SHAPE_FEATURE_NAMES,
    CameraModel,
    EyePose,
    FeatureMode,
    HapticReading,
    StereoFrame,
    feature_dim,
    feature_names,
    mode_of_dim,
)
from roger_perception.config import PerceptionConfig
from roger_perception.perception import Perception
from roger_perception.shape import H_MAX_M

DATA = Path(__file__).parent / "data" / "paper_features.npz"


def _frames() -> list[StereoFrame]:
    d = np.load(DATA)
    w, h, focal = d["camera"]
    camera = CameraModel(int(w), int(h), float(focal))
    frames = []
    for i in range(len(d["left"])):
        hp = d["haptic"][i]
        haptic = None if math.isnan(hp[0]) else HapticReading(
            int(hp[0]), bool(hp[1]), tuple(float(v) for v in hp[2:5]), float(hp[5]))
        frames.append(StereoFrame(float(d["stamp"][i]), int(d["goal_id"][i]), d["left"][i],
                                  d["right"][i], camera, EyePose(d["lpos"][i], d["lrot"][i]),
                                  EyePose(d["rpos"][i], d["rrot"][i]), int(d["exposures"][i]),
                                  haptic))
    return frames


def _features(mode: str) -> tuple[np.ndarray, np.ndarray, list[int]]:
    perception = Perception(PerceptionConfig(features=mode))
    feats, known, counts = [], [], []
    for frame in _frames():
        rois = perception.process(frame)
        counts.append(len(rois))
        feats += [r.features for r in rois]
        known += [r.known for r in rois]
    return np.stack(feats), np.stack(known), counts


def test_the_paper_mode_gives_the_recorded_eleven_features_bit_for_bit() -> None:
    d = np.load(DATA)
    for mode in ("paper", "extended"):
        feats, known, counts = _features(mode)
        assert counts == d["rois_per_frame"].tolist(), mode
        assert feats.shape == (len(d["paper_features"]), feature_dim(mode))
        # The eleven of equations 1-5 do not change with the mode, to the bit.
        assert np.array_equal(feats[:, :len(FEATURE_NAMES)], d["paper_features"]), mode
        assert np.array_equal(known[:, :len(FEATURE_NAMES)], d["paper_known"]), mode


def test_the_extended_mode_appends_the_shape_evidence() -> None:
    feats, known, _ = _features("extended")
    extra = feats[:, len(FEATURE_NAMES):]
    extra_known = known[:, len(FEATURE_NAMES):]
    assert extra.shape[1] == len(SHAPE_FEATURE_NAMES)
    assert np.all((extra >= 0) & (extra <= 1)) and np.all(extra[~extra_known] == 0)
    h = list(SHAPE_FEATURE_NAMES).index("H")
    # Every ROI whose outline is its own (I known) has a height; shapes.yaml's objects
    # stand 0.17-0.2 m tall, read (shape.py) at most their top's far rim above the top.
    seen = known[:, 0]
    assert extra_known[seen, h].all()
    z = extra[seen, h] * H_MAX_M
    assert np.all((z > 0.12) & (z < 0.40)), z


@pytest.mark.parametrize("mode", list(FeatureMode))
def test_each_mode_names_its_layout(mode: FeatureMode) -> None:
    names = feature_names(mode)
    assert names[:len(FEATURE_NAMES)] == FEATURE_NAMES
    assert mode_of_dim(len(names)) is mode
    assert FeatureMode.parse(mode.value) is mode


def test_an_unknown_mode_is_refused_naming_the_choices() -> None:
    with pytest.raises(ValueError, match="paper.*extended"):
        FeatureMode.parse("fancy")
    with pytest.raises(Exception, match="PerceptionConfig.features"):
        PerceptionConfig(features="fancy")
    with pytest.raises(ValueError, match="12 features"):
        mode_of_dim(12)


def test_touch_reads_the_top_height_the_curvature_and_the_crease() -> None:
    from roger_common.types import TactileContact
    from roger_perception.shape import CREASE_FULL_RAD, CREASE_RAD, TK_SCALE_M, tactile_shape
    flat = [TactileContact((0.6, 0.0, 0.12), (0.0, 0.0, 1.0)),
            TactileContact((0.64, 0.0, 0.121), (0.0, 0.0, 1.0), (0.04, 0.0))]
    th, tk, tc, _ = tactile_shape(flat)
    assert th == pytest.approx(0.121 / H_MAX_M) and tk == pytest.approx(0.0, abs=1e-6)
    assert tc == pytest.approx(0.0, abs=1e-6)
    # A flank 60 degrees from a flat touch: a crease, no curvature.
    tilt = np.radians(60.0)
    assert tilt > CREASE_RAD
    flank = TactileContact((0.63, 0.0, 0.07), (np.sin(tilt), 0.0, np.cos(tilt)), (0.04, 0.0))
    th, tk, tc, _ = tactile_shape([flat[0], flank])
    assert th == pytest.approx(0.12 / H_MAX_M) and tk == pytest.approx(0.0, abs=1e-6)
    assert tc == pytest.approx(1.0)
    # Every crease of 45 degrees (CREASE_FULL_RAD) or more reads 1: the 60 and the 120
    # degrees of a prism's ridge alike.
    assert CREASE_FULL_RAD < tilt
    other = TactileContact((0.66, 0.0, 0.07), (-np.sin(tilt), 0.0, np.cos(tilt)), (0.04, 0.0))
    assert tactile_shape([flank, other])[2] == pytest.approx(1.0)
    # Touches on a sphere of radius R: TK = TK_SCALE_M / R wherever they land, no crease.
    for radius, centre, dirs in ((0.08, (0.5, 0.1, 0.0), ((0, 0), (0.3, 0.1), (-0.2, 0.25),
                                                          (0.05, -0.35))),
                                 (0.06, (0.7, -0.2, 0.0), ((0.1, 0.05), (0.4, 0.0),
                                                           (-0.3, -0.2)))):
        touches = []
        for dx, dy in dirs:
            n = np.array([dx, dy, np.sqrt(1 - dx * dx - dy * dy)])
            touches.append(TactileContact(tuple(np.add(centre, radius * n)), tuple(n)))
        th, tk, tc, _ = tactile_shape(touches)
        assert tk == pytest.approx(TK_SCALE_M / radius, rel=0.03), radius
        assert tc == pytest.approx(0.0, abs=0.04), radius  # 0.03 rad
    assert tactile_shape([]) is None
    # A touch on a ridge, its normal tipped 25 degrees to one flank (less than a crease),
    # 3 cm along the ridge from a flat touch: the normal turns across the chord, not along
    # it, so no curvature (the whole turn, 0.44 rad over 3 cm, would read a 7 cm radius).
    tip = np.radians(25.0)
    assert tip < CREASE_RAD
    ridge = [TactileContact((0.6, 0.0, 0.12), (0.0, 0.0, 1.0)),
             TactileContact((0.63, 0.0, 0.12), (0.0, np.sin(tip), np.cos(tip)), (0.03, 0.0))]
    assert tactile_shape(ridge)[1] == pytest.approx(0.0, abs=1e-6)
    # Normals whose noise tips them about a flat face read no curvature on average: the
    # turn is as likely against the chord as along it.
    rng = np.random.default_rng(3)
    tks = []
    for _ in range(200):
        touches = []
        for dx, dy in ((0.0, 0.0), (0.04, 0.0), (-0.02, 0.035), (-0.02, -0.035)):
            n = np.array([0.0, 0.0, 1.0]) + rng.normal(0.0, 0.03, 3)
            touches.append(TactileContact((0.6 + dx, dy, 0.12), tuple(n / np.linalg.norm(n))))
        tks.append(tactile_shape(touches)[1])
    assert np.median(tks) == pytest.approx(0.0, abs=1e-6) and np.quantile(tks, 0.9) < 0.03


def test_a_creased_objects_touches_read_no_curvature() -> None:
    """TK is the curvature of a smooth surface (times 1 - TC): an edge touch whose normal
    turns along the chord reads as a curve on its own, but not on an object whose touches
    cross a crease (a prism's ridge), where the faces are flat."""
    from roger_common.types import TactileContact
    from roger_perception.shape import CREASE_FULL_RAD, TK_SCALE_M, touch_shape
    up = (0.0, 0.0, 1.0)
    tip = np.radians(10.0)  # an edge's normal, tipped along the chord
    edge = (TactileContact((0.6, 0.0, 0.12), up),
            TactileContact((0.64, 0.0, 0.12), (np.sin(tip), 0.0, np.cos(tip))))
    tilt = np.radians(60.0)
    ridge = (TactileContact((0.6, 0.0, 0.12), up),
             TactileContact((0.63, 0.0, 0.09), (np.sin(tilt), 0.0, np.cos(tilt))))
    curve = np.sin(tip) * 0.04 / 0.04 ** 2  # the pair's turn along the chord / its length
    alone = touch_shape([edge])
    assert alone is not None
    assert alone[1] == pytest.approx(curve * TK_SCALE_M * (1 - alone[2]), rel=1e-6)
    assert alone[2] == pytest.approx(0.0, abs=0.01)
    # Two readings across the ridge (no smooth pair: 60 degrees is a crease) and the edge's:
    # the pooled curvature is the edge's, the crease the readings' median.
    assert np.radians(60.0) - curve * np.hypot(0.03, 0.03) > CREASE_FULL_RAD
    pooled = touch_shape([ridge, ridge, edge])
    assert pooled is not None
    assert pooled[2] == pytest.approx(1.0) and pooled[1] == pytest.approx(0.0, abs=1e-9)
    # One of three across the ridge: the median crease is the edge's, and the curve stays.
    mostly_smooth = touch_shape([ridge, edge, edge])
    assert mostly_smooth is not None
    assert mostly_smooth[1] == pytest.approx(curve * TK_SCALE_M * (1 - mostly_smooth[2]))
    assert mostly_smooth[1] > 0.9 * curve * TK_SCALE_M


def test_touches_of_several_readings_of_one_object_are_pooled() -> None:
    """A second haptic improvement adds its touches to the first's (haptic.HapticMemory):
    a reading that missed the prism's ridge no longer decides its crease alone, and the
    curvature is fitted over every reading's pairs."""
    from roger_common.types import HapticReading, TactileContact
    from roger_perception.haptic import TOUCH_READINGS, HapticMemory
    from roger_perception.shape import tactile_shape, touch_shape
    up = (0.0, 0.0, 1.0)
    tilt = np.radians(60.0)
    flank = (np.sin(tilt), 0.0, np.cos(tilt))
    missed = (TactileContact((0.6, 0.0, 0.10), flank), TactileContact((0.62, 0.0, 0.09), flank))
    crossed = (TactileContact((0.6, 0.0, 0.12), up), TactileContact((0.63, 0.0, 0.09), flank))
    assert tactile_shape(missed)[2] == pytest.approx(0.0, abs=1e-6)
    assert tactile_shape(crossed)[2] == pytest.approx(1.0)
    # Median over readings: two of three crossed the ridge.
    assert touch_shape([missed, crossed, crossed])[2] == pytest.approx(1.0)
    assert touch_shape([missed, missed, crossed])[2] == pytest.approx(0.0, abs=1e-6)
    # The memory keeps the last TOUCH_READINGS readings at one position, and a reading
    # elsewhere starts its own object.
    memory = HapticMemory(0.05)

    def reading(contacts: tuple[TactileContact, ...], x: float = 0.6) -> HapticReading:
        return HapticReading(arm=0, contact=True, weight=0.5, position=(x, 0.0, 0.1),
                             contacts=contacts)

    memory.add(reading(missed))
    assert memory.touch_near((0.6, 0.0, 0.1))[2] == pytest.approx(0.0, abs=1e-6)
    memory.add(reading(crossed))
    memory.add(reading(crossed))
    assert memory.touch_near((0.6, 0.0, 0.1))[2] == pytest.approx(1.0)
    for _ in range(TOUCH_READINGS):
        memory.add(reading(missed))
    assert memory.touch_near((0.6, 0.0, 0.1))[2] == pytest.approx(0.0, abs=1e-6)
    memory.add(reading(crossed, x=0.9))
    assert memory.touch_near((0.9, 0.0, 0.1))[2] == pytest.approx(1.0)
    assert memory.touch_near((0.6, 0.0, 0.1))[2] == pytest.approx(0.0, abs=1e-6)
    # A reading without touches (an old recording) changes the weight, not the touches.
    memory.add(HapticReading(arm=0, contact=True, weight=0.7, position=(0.9, 0.0, 0.1)))
    assert memory.weight_near((0.9, 0.0, 0.1)) == pytest.approx(0.7)
    assert memory.touch_near((0.9, 0.0, 0.1))[2] == pytest.approx(1.0)


def _image(depth_of) -> tuple[tuple[float, ...], float]:
    """A 21 x 21 tactile image (2 mm pitch) of the surface depth ``depth_of(x, y)`` below
    the pad (metres, pad centred on 0), NaN beyond the skin's 3 mm."""
    grid = np.linspace(-0.02, 0.02, 21)
    depth = np.array([[depth_of(x, y) for x in grid] for y in grid]).ravel()
    depth[~(depth <= 0.003)] = np.nan
    return tuple(float(v) for v in depth), float(grid[1] - grid[0])


def test_a_tactile_image_shows_a_ridge_only_where_the_surface_falls_away_on_both_sides(
        ) -> None:
    from roger_common.types import TactileContact
    from roger_perception.shape import tactile_ridge, tactile_shape
    slope = math.tan(math.radians(60.0))  # a prism's flanks

    def touch(depth_of) -> TactileContact:
        image, pitch = _image(depth_of)
        return TactileContact((0.6, 0.0, 0.1), (0.0, 0.0, 1.0), image=image, pitch=pitch)

    ridges = [touch(lambda x, y, c=c: slope * abs(x - c)) for c in (0.0, 0.008, -0.012)]
    turned = math.radians(35.0)
    ridges.append(touch(lambda x, y: slope * abs(math.cos(turned) * x + math.sin(turned) * y)))
    for ridge in ridges:
        assert tactile_ridge(ridge)
    not_ridges = {
        "a flat top under the whole pad": touch(lambda x, y: 0.0),
        "a flat top's edge under the pad's border": touch(
            lambda x, y: 0.0 if x > 0.016 else 0.05),
        "half the pad over a flat top": touch(lambda x, y: 0.0 if x > 0.0 else 0.05),
        "a flank under the pad's border": touch(lambda x, y: slope * (0.02 - x)),
        "a sphere's top": touch(lambda x, y: (x * x + y * y) / (2 * 0.04)),
        "a ridge's end, too short": touch(
            lambda x, y: slope * abs(x) if y > 0.012 else 0.05),
        "no image": TactileContact((0.6, 0.0, 0.1), (0.0, 0.0, 1.0)),
    }
    for what, contact in not_ridges.items():
        assert not tactile_ridge(contact), what
    # A single touch on a ridge crosses a full crease; the same touch without its image
    # finds none (the flat pad reports a vertical normal on a ridge).
    assert tactile_shape([ridges[0]])[2] == pytest.approx(1.0)
    blind = TactileContact(ridges[0].point, ridges[0].normal)
    assert tactile_shape([blind])[2] == pytest.approx(0.0, abs=1e-6)
    assert tactile_shape([not_ridges["a flat top under the whole pad"]])[2] == \
        pytest.approx(0.0, abs=1e-6)


def test_a_reading_of_edges_only_that_crossed_no_crease_leaves_the_crease_unknown() -> None:
    """Touches whose images are all lines (a ridge under the pad's border, never crossed)
    cannot tell a ridge from a smooth top: TC unknown (NaN), and TK read as smooth. One
    touch that pressed an area (a flat top, a sphere's top) makes a crease of 0 known; a
    ridge under the pad, a full crease; touches without images, as before."""
    from roger_common.types import TactileContact
    from roger_perception.shape import pressed_area, tactile_shape, touch_shape
    slope = math.tan(math.radians(60.0))

    def touch(depth_of, x: float = 0.6) -> TactileContact:
        image, pitch = _image(depth_of)
        return TactileContact((x, 0.0, 0.1), (0.0, 0.0, 1.0), image=image, pitch=pitch)

    border = touch(lambda x, y: slope * (0.02 - x))          # a flank under the border
    border_too = touch(lambda x, y: slope * (x + 0.02), x=0.63)
    flat = touch(lambda x, y: 0.0)
    sphere = touch(lambda x, y: (x * x + y * y) / (2 * 0.04))
    ridge = touch(lambda x, y: slope * abs(x))
    assert not pressed_area(border) and not pressed_area(ridge)
    assert pressed_area(flat) and pressed_area(sphere)
    th, tk, tc, tr = tactile_shape([border, border_too])
    assert math.isnan(tc) and math.isfinite(th) and tk == pytest.approx(0.0, abs=1e-6)
    assert tactile_shape([border, flat])[2] == pytest.approx(0.0, abs=1e-6)
    assert tactile_shape([sphere])[2] == pytest.approx(0.0, abs=1e-6)
    assert tactile_shape([border, ridge])[2] == pytest.approx(1.0)
    blind = [TactileContact(c.point, c.normal) for c in (border, border_too)]
    assert tactile_shape(blind)[2] == pytest.approx(0.0, abs=1e-6)
    # Pooled readings: the unknown one is left out of the median, a known one decides.
    assert touch_shape([[border, border_too], [ridge]])[2] == pytest.approx(1.0)
    assert touch_shape([[border, border_too], [flat]])[2] == pytest.approx(0.0, abs=1e-6)


def test_a_tactile_image_reads_a_flat_tops_rim_straight_or_round() -> None:
    from roger_common.types import TactileContact
    from roger_perception.shape import TR_SCALE_M, tactile_rim, tactile_shape

    def touch(depth_of) -> TactileContact:
        image, pitch = _image(depth_of)
        return TactileContact((0.6, 0.0, 0.1), (0.0, 0.0, 1.0), image=image, pitch=pitch)

    off = 0.05  # the ground, far below the skin's range
    for angle in (0.0, 0.3, 0.8):  # a box's edge under the pad, turned
        c, s = math.cos(angle), math.sin(angle)
        # Straight: within the staircase of 2 mm taxels (a 7 cm rim reads 14 / m).
        assert tactile_rim(touch(lambda x, y: -0.0005 if c * x + s * y < 0.006 else off)) \
            < 4.0, angle
    for radius in (0.03, 0.05, 0.07):  # a cylinder's rim, its centre off the pad
        rims = []
        for dx in (0.0, 0.0005, 0.001, 0.0015):  # where the rim falls between taxels
            for dy in (0.0, 0.003, 0.007):
                centre = (-radius + 0.008 + dx, dy)
                rims.append(tactile_rim(touch(lambda x, y, c=centre, r=radius: -0.0005 if
                                              math.hypot(x - c[0], y - c[1]) < r else off)))
        assert all(r is not None for r in rims), radius
        # Each within the 2 mm taxels' staircase; their median within 15 %.
        assert np.median(rims) == pytest.approx(1.0 / radius, rel=0.15), (radius, rims)
        assert all(0.6 / radius < r < 1.4 / radius for r in rims), (radius, rims)
    # A box's corner: two straight edges at a right angle, a polygon's rim, straight.
    corners = {
        "a box's corner": touch(lambda x, y: -0.0005 if x < 0.004 and y < 0.004 else off),
        "a box's corner turned 45 degrees": touch(
            lambda x, y: -0.0005 if x > abs(y) - 0.012 else off),
        "a corner beyond the pad, its edges cutting two of the pad's corners": touch(
            lambda x, y: -0.0005 if x > abs(y) - 0.03 else off),
        "a corner turned 20 degrees, off the centre": touch(
            lambda x, y: -0.0005 if (0.94 * (x - 0.003) + 0.34 * (y + 0.004) < 0
                                     and -0.34 * (x - 0.003) + 0.94 * (y + 0.004) < 0)
            else off),
    }
    for what, contact in corners.items():
        assert tactile_rim(contact) == 0.0, what
    # Two straight edges not at a right angle (a prism's end seen flat would be 60
    # degrees; no top here has one) are no corner, and no one curve either.
    assert tactile_rim(touch(lambda x, y: -0.0005 if x > 0.58 * abs(y) - 0.01 else off)) \
        is None
    no_rim = {
        "the whole pad on a top": touch(lambda x, y: -0.0005),
        "an edge too short to tell": touch(lambda x, y: -0.0005 if x + y > -0.024 else off),
        "a sphere's top": touch(lambda x, y: (x * x + y * y) / (2 * 0.05) - 0.0005),
        "a ridge": touch(lambda x, y: 1.7 * abs(x) - 0.0005),
        "no image": TactileContact((0.6, 0.0, 0.1), (0.0, 0.0, 1.0)),
    }
    for what, contact in no_rim.items():
        assert tactile_rim(contact) is None, what
    # TR: the median rim over the touches, scaled; unknown (NaN) without one.
    arc = touch(lambda x, y: -0.0005 if math.hypot(x + 0.042, y - 0.003) < 0.05 else off)
    assert tactile_shape([arc, no_rim["the whole pad on a top"]])[3] == pytest.approx(
        TR_SCALE_M * tactile_rim(arc))
    assert tactile_rim(arc) == pytest.approx(1.0 / 0.05, rel=0.3)
    assert math.isnan(tactile_shape([no_rim["the whole pad on a top"]])[3])
