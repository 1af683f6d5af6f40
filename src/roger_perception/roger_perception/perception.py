"""Perception: stereo frame in, regions of interest with features and activation out.

One call of ``Perception.process`` per stereo pair:

1. visual buffer: LoG of both retinas at the three resolutions (log_filter);
2. ROIs of each retina (segmentation), paired across the retinas and triangulated into
   the robot frame with the frame's eye poses (stereo);
3. features of each paired ROI, equations 1-5 (features; W from HapticMemory);
4. pre-attentive activation of each ROI (activation).

State kept between frames: haptic readings by position (so later frames carry W), the
previous frame's smoothed left retina and left-eye view (for visual motion), and the last
visual buffer (for viewers).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from roger_common.errors import MessageError
from roger_common.geometry import as_point, project_point
from roger_common.types import (
    SHAPE_FEATURE_NAMES,
    SIZE_INDEX,
    WEIGHT_INDEX,
    CameraModel,
    FeatureMode,
    Roi,
    StereoFrame,
)
from roger_perception.activation import (
    MotionView,
    is_mapped,
    motion_image,
    pre_attentive_activation,
    visual_motion_batch,
)
from roger_perception.config import PerceptionConfig
from roger_perception.features import (
    LabelNeighbours,
    Rim,
    assemble,
    g_max,
    intensity_texture,
    own_vicinity,
    rim_samples,
    sample_at,
    size_feature,
    stereo_feature,
    vicinity_radius,
    weight_feature,
)
from roger_perception.fovea import (
    WHOLE,
    FoveaLooks,
    fixated,
    fovea_steps,
    outline_feature,
    top_against_other,
)
from roger_perception.fovea_layers import (
    Layer,
    Layers,
    fixated_layers,
    project_layer,
    retina_points,
)
from roger_perception.haptic import HapticMemory, touches
from roger_perception.log_filter import log_pyramid
from roger_perception.roi_finder import SeenObject, find_objects, raster_index
from roger_perception.segmentation import background_level, blob_of, ground_level, window_boxes
from roger_perception.shape import (
    AP_CREASE,
    creased_albedo,
    smoothed_grey,
    sphere_albedo,
    top_brightness,
    top_height,
    visual_features,
)
from roger_perception.stereo import (
    fundamental_matrix,
    relative_disparities_batch,
    relief_per_pixel,
)

#: Names of the stages timed in ``Perception.last_timings``.
STAGES: tuple[str, ...] = ("log", "segment", "match", "features", "activation")
#: Index of A (the brightest surface's grey) among the extended features.
_A: int = SHAPE_FEATURE_NAMES.index("A")
_AS: int = SHAPE_FEATURE_NAMES.index("AS")
#: Indices of touch's shape (TH, TK, TC, TR: ``shape.touch_shape``) and of AP.
_TOUCH: slice = slice(SHAPE_FEATURE_NAMES.index("TH"), SHAPE_FEATURE_NAMES.index("TR") + 1)
_TC: int = SHAPE_FEATURE_NAMES.index("TC")
_AP: int = SHAPE_FEATURE_NAMES.index("AP")


class Perception:
    """The perceptual buffer of section 2: visual buffer, ROIs, features, activation.

    Args:
        config: Parameters; validated on construction of the config.
        seed: Kept for interface symmetry; the perception core is deterministic (no
            random sampling), so the same frame always gives the same ROIs.
    """

    def __init__(self, config: PerceptionConfig | None = None, seed: int = 0) -> None:
        self.config = PerceptionConfig() if config is None else config
        cv2.setNumThreads(self.config.cv_threads)
        self.seed = int(seed)
        self._gmax = g_max(self.config)
        self._vicinity = [vicinity_radius(s, self.config) for s in self.config.log_sigmas]
        self._half_windows = [max(1, round(self.config.match_window_sigmas * s))
                              for s in self.config.log_sigmas]
        self.haptic_memory = HapticMemory(self.config.haptic_radius_m)
        self.fovea_looks = FoveaLooks(self.config.haptic_radius_m)
        #: Layers behind fixated ROIs the two foveae found (``fovea_layers``), by position.
        self.layers = Layers(self.config.haptic_radius_m)
        #: Layers in front of fixated ROIs (a nearer object's edge that joined them).
        self.fronts = Layers(self.config.haptic_radius_m)
        #: The last fovea's steps (``fovea.fovea_steps``), computed once for its ROIs.
        self._fovea_steps: tuple[np.ndarray, tuple[np.ndarray, float]] | None = None
        #: The last left retina and its three-pixel row means (``shape.smoothed_grey``), for A.
        self._smoothed: tuple[np.ndarray, np.ndarray] | None = None
        #: The last left retina and its ground grey (``segmentation.background_level``),
        #: for AS.
        self._ground: tuple[np.ndarray, float] | None = None
        self._previous_view: MotionView | None = None
        self._last_log: tuple[list[np.ndarray], list[np.ndarray]] = ([], [])
        self.last_timings: dict[str, float] = dict.fromkeys(STAGES, 0.0)
        #: Left-retina ROI of every pixel of the last frame: 0 none, roi_id + 1 (viewers
        #: draw the paper's thin lines between ROIs from it; tests score it).
        self.last_roi_labels: np.ndarray = np.zeros((0, 0), np.int32)

    def d_max(self, camera: CameraModel) -> float:
        """D_max of equation 4, metres: the width of the retina's field of view at
        ``size_view_distance_m`` (from the lens: ``width / focal_px``)."""
        return self.config.size_view_distance_m * camera.width / camera.focal_px

    @property
    def g_max(self) -> tuple[float, ...]:
        """G_max^(k) of equations 1-2 for k = 1, 2, 3."""
        return tuple(self._gmax)

    @property
    def last_log(self) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """Left and right LoG responses (k = 1, 2, 3) of the last frame, for viewers."""
        return self._last_log

    def reset(self) -> None:
        """Forget haptic readings, the previous frame and the last visual buffer."""
        self.haptic_memory.clear()
        self.fovea_looks.clear()
        self.layers.clear()
        self.fronts.clear()
        self._previous_view = None
        self._last_log = ([], [])
        self.last_roi_labels = np.zeros((0, 0), np.int32)
        self.last_timings = dict.fromkeys(STAGES, 0.0)

    def process(self, frame: StereoFrame,
                mapped_positions: Sequence[tuple[float, float, float]] = ()) -> list[Roi]:
        """Turn one stereo pair into ROIs.

        Args:
            frame: The stereo pair with its camera model and eye poses.
            mapped_positions: Robot-frame positions already in the spatial map; a ROI
                within ``mapped_radius_m`` of one is mapped.

        Returns:
            One Roi per object seen by both eyes, ids 0..n-1 in left-retina raster order.

        Raises:
            MessageError: When the images do not match the camera model.
        """
        cfg = self.config
        _check_frame(frame)
        timings = dict.fromkeys(STAGES, 0.0)
        t0 = time.perf_counter()
        left_log = log_pyramid(frame.left, cfg)
        right_log = log_pyramid(frame.right, cfg)
        t1 = time.perf_counter()
        timings["log"] = t1 - t0
        seen, labels = find_objects(frame, cfg)  # eqs. of section 3: ROIs and stereo
        t2 = time.perf_counter()
        timings["segment"] = t2 - t1
        if cfg.border_margin_px > 0:
            size = (frame.camera.width, frame.camera.height)
            seen = [o for o in seen if not _near_border(o.blob.bbox, size, cfg.border_margin_px)]
        if cfg.fovea_layers and cfg.feature_mode is FeatureMode.EXTENDED:
            seen = self._part_layers(frame, seen)
        f = fundamental_matrix(frame.camera, frame.left_pose, frame.right_pose)
        t3 = time.perf_counter()
        timings["match"] = t3 - t2
        # Metric size of each ROI: the side of a square of its silhouette's area at its
        # depth (one length for every shape, from all its pixels: its width alone jitters
        # by the pixels at its two ends).
        sizes = [math.sqrt(o.blob.area) * o.depth / frame.camera.focal_px for o in seen]
        if frame.haptic is not None:
            self.haptic_memory.add(frame.haptic, [o.position for o in seen], sizes)
        magnitudes = [np.abs(g) for g in left_log]
        gmax = np.asarray(self._gmax)
        image_area = float(frame.camera.width * frame.camera.height)
        moving = motion_image(frame.left, cfg)
        rois: list[Roi] = []
        roi_labels = np.zeros_like(labels)
        for roi_id, obj in enumerate(seen):
            u0, v0, u1, v1 = obj.blob.bbox
            roi_labels[v0:v1, u0:u1][obj.blob.mask] = roi_id + 1
        near = LabelNeighbours(roi_labels)
        windows = window_boxes(frame.left, roi_labels, [o.blob.bbox for o in seen],
                               cfg.window_sigmas)
        # Two passes over the ROIs around one stereo call for all of them (the disparity
        # search costs little per sample but much per call). Everything up to the
        # activation counts as "features", the stereo call included.
        measured: list[_Measured] = []
        for roi_id, obj in enumerate(seen):
            ta = time.perf_counter()
            bl = obj.blob
            own = roi_id + 1
            rim = rim_samples(bl.mask, bl.bbox, near, own, cfg.samples_m)
            samples = []
            for mag, r in zip(magnitudes, self._vicinity, strict=True):
                win, (wu, wv) = own_vicinity(mag, roi_labels, own, bl.bbox, r)
                samples.append(sample_at(win, rim.points - (wu, wv)))
            intensity, texture = intensity_texture(np.stack(samples), gmax)  # eqs. 1-2
            depth_l = project_point(frame.camera, frame.left_pose, obj.position)[2]
            depth_r = project_point(frame.camera, frame.right_pose, obj.position)[2]
            measured.append(_Measured(rim, intensity, texture, depth_l / depth_r))
            timings["features"] += time.perf_counter() - ta
        ta = time.perf_counter()
        all_disparities = relative_disparities_batch(
            left_log, right_log, f,
            [(obj.blob.centroid, obj.right_px, m.rim.points, m.magnification)
             for obj, m in zip(seen, measured, strict=True)],
            self._half_windows, cfg.stereo_search_px, cfg.stereo_smoothness)
        timings["features"] += time.perf_counter() - ta
        ta = time.perf_counter()
        motions = visual_motion_batch(
            moving, [(obj.blob.mask, obj.blob.bbox, obj.depth) for obj in seen],
            frame.camera, frame.left_pose, self._previous_view, cfg)
        # The mapped positions as one array, converted once for all ROIs.
        mapped_array = np.asarray(mapped_positions, float).reshape(-1, 3)
        timings["activation"] += time.perf_counter() - ta
        for roi_id, (obj, m, disparities) in enumerate(zip(seen, measured, all_disparities,
                                                           strict=True)):
            ta = time.perf_counter()
            bl = obj.blob
            position = obj.position
            rim = m.rim
            metres_per_px = relief_per_pixel(frame.camera, frame.left_pose, frame.right_pose,
                                             position)
            relief = disparities * (metres_per_px if math.isfinite(metres_per_px) else 0.0)
            # A sample whose disparity search found no minimum inside the search range, or
            # whose relief exceeds the object's own size, is a failed match, not a shape.
            size_m = sizes[roi_id]
            relief[np.abs(relief) > size_m] = np.nan
            stereo, stereo_known = stereo_feature(relief, cfg.s_max_m, cfg.min_stereo_samples)
            weight_kg = self.haptic_memory.weight_near(position)
            weight = None if weight_kg is None else weight_feature(weight_kg, cfg.w_max_kg)
            feats, known = assemble(m.intensity, m.texture, stereo,
                                    size_feature(size_m, self.d_max(frame.camera)),
                                    weight, stereo_known)  # eqs. 3-5
            if rim.own_share < cfg.min_rim_share or rim.on_border:
                # Too little of its silhouette is its own edge (behind another object), or
                # the retina's edge cuts it: I, T, S and D would measure a part of it, seen
                # from the rim of the view (docs/perception.md, "A ROI cut by the retina's
                # edge"). The robot measures it when it looks at it.
                known[:WEIGHT_INDEX] = False
                feats[:WEIGHT_INDEX] = 0.0
            elif any(seen[n - 1].depth < obj.depth for n in rim.neighbours):
                # Its silhouette is cut by a nearer object: its extent is not the object's.
                known[SIZE_INDEX] = False
                feats[SIZE_INDEX] = 0.0
            if self.config.feature_mode is FeatureMode.EXTENDED:
                feats, known = self._extend(feats, known, frame, obj.blob, position,
                                            roi_labels, roi_id + 1)
            tb = time.perf_counter()
            retinal_size = bl.area / image_area
            motion = motions[roi_id]
            tactile = 1.0 if touches(frame.haptic, position, cfg.haptic_radius_m) else 0.0
            mapped = is_mapped(position, mapped_array, cfg.mapped_radius_m)
            activation = pre_attentive_activation(retinal_size, bl.mean_intensity, motion,
                                                  tactile, mapped, cfg)
            rois.append(Roi(
                roi_id=roi_id, bbox=windows[roi_id], position=position, features=feats,
                known=known, activation=activation, retinal_size=retinal_size,
                mean_intensity=bl.mean_intensity, motion=motion, tactile=tactile,
                mapped=mapped, cut=obj.cut, size_m=size_m,
            ))
            tc = time.perf_counter()
            timings["features"] += tb - ta
            timings["activation"] += tc - tb
        self._previous_view = MotionView(moving, frame.camera, frame.left_pose)
        self._last_log = (left_log, right_log)
        self.last_roi_labels = roi_labels
        self.last_timings = timings
        return rois


    def _part_layers(self, frame: StereoFrame, seen: list[SeenObject]) -> list[SeenObject]:
        """Part ROIs where a layer behind or in front was found (``fovea_layers``): first
        the fixated ROI on a look with both foveae (the layers found, or none, are kept by
        the ROI's position), then every ROI near a kept layer's position whose pixels the
        layer's points fall on. A layer in front is a nearer object's edge: it leaves the
        ROI, and is a ROI of its own only where no other ROI of the frame stands near its
        place (the nearer object's own ROI). Returns the objects in left-retina raster
        order."""
        cfg = self.config
        camera = frame.camera
        if (frame.fovea is not None and frame.fovea_right is not None
                and frame.fovea_camera is not None):
            for obj in seen:
                if obj.cut or not fixated(obj.blob.mask, obj.blob.bbox, camera):
                    continue
                behind, front = fixated_layers(
                    frame.fovea, frame.fovea_right, frame.fovea_camera, camera,
                    frame.left_pose, frame.right_pose, obj.blob.mask, obj.blob.bbox,
                    obj.depth, obj.width_px * obj.depth / camera.focal_px,
                    cfg.min_roi_pixels, position=obj.position)
                if front is not None:
                    front = self._front_layer(front, obj, seen, frame)
                self.layers.put(obj.position, behind)
                self.fronts.put(obj.position, front)
        if not len(self.layers) and not len(self.fronts):
            return seen
        bg = background_level(frame.left)
        if len(self.fronts):
            out: list[SeenObject] = []
            for obj in seen:
                found = self._kept_part(self.fronts, obj, frame, min_layer=1)
                if found is None:
                    out.append(obj)
                    continue
                near, near_depth = found
                out.append(_part(obj, obj.blob.mask & ~near, obj.depth, frame, bg))
                piece = _part(obj, near, near_depth, frame, bg)
                if int(near.sum()) >= cfg.min_roi_pixels and not any(
                        other is not obj and math.dist(other.position[:2], piece.position[:2])
                        <= self.fronts.radius for other in seen):
                    out.append(piece)
            seen = out
        if len(self.layers):
            out = []
            for obj in seen:
                found = self._kept_part(self.layers, obj, frame, cfg.min_roi_pixels)
                if found is None:
                    out.append(obj)
                    continue
                far, far_depth = found
                out.append(_part(obj, obj.blob.mask & ~far, obj.depth, frame, bg))
                out.append(_part(obj, far, far_depth, frame, bg))
            seen = out
        seen.sort(key=lambda o: raster_index(o.blob, camera.width))
        return seen

    def _front_layer(self, found: Layer, obj: SeenObject, seen: Sequence[SeenObject],
                     frame: StereoFrame) -> Layer | None:
        """A layer in front found in the fovea, confirmed by a nearer ROI beside it at its
        depth, and its extent in the retina: the ROI's pixels joined to the occluder's
        across greys of one surface (``front_extent``); placed at the layer's depth. None
        where either fails."""
        camera = frame.camera
        occluder = _occluder_beside(found, obj, seen, camera)
        if occluder is None:
            return None
        step, ground_max = self._grey_step(frame, seen)
        grown = front_extent(obj, occluder, frame.left, step, ground_max, seeds=found.mask,
                             own=found.own)
        if grown is None or int((obj.blob.mask & ~grown).sum()) < self.config.min_roi_pixels:
            return None
        return Layer(mask=grown, points=retina_points(camera, frame.left_pose, grown,
                                                      obj.blob.bbox, found.depth),
                     depth=found.depth, samples=found.samples, front=True)

    @staticmethod
    def _grey_step(frame: StereoFrame, seen: Sequence[SeenObject]) -> tuple[float, float]:
        """(step, ground_max) of the left retina: two 4-neighbours of one surface differ by
        less than ``STEP_SIGMAS`` sqrt 2 times its own pixel noise, measured on the ground
        off every ROI (``segmentation.ground_level``); a pixel no brighter than the ground's
        level plus ``GROUND_SIGMAS`` times it is ground."""
        fg = np.zeros(frame.left.shape, np.uint8)
        for o in seen:
            u0, v0, u1, v1 = o.blob.bbox
            fg[v0:v1, u0:u1] |= o.blob.mask.astype(np.uint8)
        level, spread = ground_level(np.asarray(frame.left, np.float32), fg)
        spread = max(spread, 1e-4)
        return STEP_SIGMAS * math.sqrt(2.0) * spread, level + GROUND_SIGMAS * spread

    def _kept_part(self, layers: Layers, obj: SeenObject, frame: StereoFrame,
                   min_layer: int) -> tuple[np.ndarray, float] | None:
        """The pixels of ``obj`` a kept layer near it falls on and the layer's depth along
        the left optical axis, or None."""
        if obj.cut:
            return None
        for layer in layers.near(obj.position):
            part = project_layer(layer.points, frame.camera, frame.left_pose, obj.blob.mask,
                                 obj.blob.bbox, self.config.min_roi_pixels,
                                 min_layer=min_layer)
            if part is not None:
                depths = (layer.points - frame.left_pose.position) \
                    @ frame.left_pose.rotation[:, 2]
                return part, float(np.median(depths))
        return None

    def _extend(self, feats: np.ndarray, known: np.ndarray, frame: StereoFrame, blob: Any,
                position: tuple[float, float, float], labels: np.ndarray,
                own: int) -> tuple[np.ndarray, np.ndarray]:
        """The paper's eleven features followed by the shape evidence of ``shape.py``.

        H, A and AS are unknown where I is (too little of the outline is the object's own edge, or
        the retina's edge cuts it: its top may be another object's). O is measured, under
        the same condition, on the fovea of a visual improvement, for the ROI the eye
        fixates (``fovea.fixated``); where a nearer object cuts its silhouette (D unknown:
        the ellipse is placed by the cut width) or more than 1 - ``fovea.WHOLE`` of its
        top's columns meet another ROI (``fovea.top_against_other``) only a round outline
        counts (a cut or a step between two objects adds departure); where the top's
        outline does not count and the silhouette is not cut,
        the bottom's does, unless more than 1 - ``fovea.WHOLE`` of its columns meet another
        ROI below (an object in front); and kept at the object's position
        (``fovea.FoveaLooks``: the median of its last looks), like the weight. The touch ones are
        known where a haptic reading with tactile contacts lies near, like W.
        """
        extra = np.zeros(len(SHAPE_FEATURE_NAMES), np.float32)
        extra_known = np.zeros(len(SHAPE_FEATURE_NAMES), bool)
        if known[0]:
            (h,) = visual_features(top_height(blob.mask, blob.bbox, frame.camera,
                                              frame.left_pose, position))
            if math.isfinite(h):
                extra[0], extra_known[0] = h, True
            if self._smoothed is None or self._smoothed[0] is not frame.left:
                self._smoothed = (frame.left, smoothed_grey(frame.left))
            a = top_brightness(self._smoothed[1], blob.mask, blob.bbox)
            if math.isfinite(a):
                extra[_A], extra_known[_A] = a, True
            cfg = self.config
            if self._ground is None or self._ground[0] is not frame.left:
                self._ground = (frame.left, background_level(frame.left))
            a_s = sphere_albedo(frame.left, blob.mask, blob.bbox, frame.left_pose.rotation,
                                cfg.light_direction, cfg.light_ambient, cfg.light_diffuse,
                                self._ground[1])
            if math.isfinite(a_s):
                extra[_AS], extra_known[_AS] = a_s, True
            if frame.fovea is not None and frame.fovea_camera is not None \
                    and fixated(blob.mask, blob.bbox, frame.camera):
                if self._fovea_steps is None or self._fovea_steps[0] is not frame.fovea:
                    self._fovea_steps = (frame.fovea, fovea_steps(frame.fovea))
                # O compares the outline with an ellipse as wide as the silhouette: where a
                # nearer object cuts the silhouette (D unknown), that width is not the
                # object's. A cut adds departure (a hidden cylinder's outline reads
                # straight-edged), it never takes a box's away: only a round outline counts,
                # and never the bottom's (cut as well).
                cut = not known[SIZE_INDEX]
                against = cut or top_against_other(blob.mask, blob.bbox, labels,
                                                   own) > 1.0 - WHOLE
                free_below = not cut and top_against_other(blob.mask, blob.bbox, labels, own,
                                                           below=True) <= 1.0 - WHOLE
                o = outline_feature(frame.fovea, frame.fovea_camera, frame.camera,
                                    frame.left_pose, blob.mask, blob.bbox, position,
                                    self._fovea_steps[1], round_only=against,
                                    bottom_free=free_below)
                if math.isfinite(o):
                    self.fovea_looks.add(position, o)
        o_near = self.fovea_looks.near(position)
        if o_near is not None:
            extra[1], extra_known[1] = o_near, True
        touch = self.haptic_memory.touch_near(position)
        if touch is not None:
            # TR is unknown (NaN) until a touch reached over a flat top's rim.
            values = np.asarray(touch, float)
            extra[_TOUCH] = np.nan_to_num(values)
            extra_known[_TOUCH] = np.isfinite(values)
            # AP where the touches crossed a crease and lay on a sloped face (a prism's
            # flank), from the silhouette as AS is (unknown where I is).
            if known[0] and extra_known[_TC] and extra[_TC] >= AP_CREASE:
                cfg = self.config
                if self._ground is None or self._ground[0] is not frame.left:
                    self._ground = (frame.left, background_level(frame.left))
                a_p = creased_albedo(frame.left, blob.mask, blob.bbox,
                                     self.haptic_memory.readings_near(position),
                                     frame.left_pose.position, position,
                                     cfg.light_direction, cfg.light_ambient,
                                     cfg.light_diffuse, self._ground[1])
                if math.isfinite(a_p):
                    extra[_AP], extra_known[_AP] = a_p, True
        return (np.concatenate([feats, extra]).astype(np.float32),
                np.concatenate([known, extra_known]))


#: A layer in front belongs to a nearer ROI of the frame whose pixels come within this many
#: retina pixels of it...
OCCLUDER_GAP_PX: int = 2
#: ... and whose depth lies within half its own width plus this of the layer's, metres.
OCCLUDER_DEPTH_M: float = 0.03


def _occluder_beside(layer: Layer, obj: SeenObject, seen: Sequence[SeenObject],
                     camera: CameraModel) -> SeenObject | None:
    """The nearer ROI of the frame whose edge a layer in front of ``obj`` is: beside it
    in the retina (within ``OCCLUDER_GAP_PX`` of the layer's pixels) and at the layer's
    depth (the occluder's body continues past the fixated ROI's edge), or None. A layer in
    front with no such ROI beside it (a false match on the fixated object's own faces) is
    not one."""
    u0, v0 = obj.blob.bbox[0], obj.blob.bbox[1]
    rows, cols = np.nonzero(layer.mask)
    if rows.size == 0:
        return None
    g = OCCLUDER_GAP_PX
    for other in seen:
        if other is obj:
            continue
        width = other.width_px * other.depth / camera.focal_px
        if abs(other.depth - layer.depth) > 0.5 * width + OCCLUDER_DEPTH_M:
            continue
        ou0, ov0 = other.blob.bbox[0], other.blob.bbox[1]
        om = other.blob.mask
        for r, c in zip(rows + v0 - ov0, cols + u0 - ou0, strict=True):
            window = om[max(0, r - g):max(0, r + g + 1), max(0, c - g):max(0, c + g + 1)]
            if window.size and window.any():
                return other
    return None


#: Two 4-neighbours of one surface differ by less than this many times the retina's own
#: pixel noise (of a difference: sqrt 2 sigma); the shading of a curved face steps by 1-3.
STEP_SIGMAS: float = 6.0
#: A pixel no brighter than the ground's level plus this many times its noise is ground
#: (as ``segmentation.sure_ground``).
GROUND_SIGMAS: float = 3.0


def grown_across_greys(start: np.ndarray, mask: np.ndarray, grey: np.ndarray, step: float,
                       reference: float) -> np.ndarray | None:
    """``start`` grown within ``mask`` through 4-neighbours within ``step`` of each other
    (one surface's shading), never across a larger step (two greys that are not one
    surface's) nor farther than two steps from ``reference`` (the surface's grey).
    None when nothing grows or all of ``mask`` does, or when fewer than half of the
    4-neighbour pairs across the grown part's edge within ``mask`` are a step (the growth
    stopped by drifting across one grey: the two greys cannot be told apart; no pair at
    all: ground between them, told apart)."""
    h, w = mask.shape
    grown = start & mask
    stack = [(int(r), int(c)) for r, c in zip(*np.nonzero(grown), strict=True)]
    while stack:
        r, c = stack.pop()
        for dr, dc in ((-1, 0), (1, 0), (0, -1), (0, 1)):
            nr, nc = r + dr, c + dc
            if (0 <= nr < h and 0 <= nc < w and mask[nr, nc] and not grown[nr, nc]
                    and abs(grey[nr, nc] - grey[r, c]) < step
                    and abs(grey[nr, nc] - reference) < 2 * step):
                grown[nr, nc] = True
                stack.append((nr, nc))
    rest = mask & ~grown
    if not grown.any() or not rest.any():
        return None
    steps = pairs = 0
    for a, b, ga, gb in ((grown[:, :-1], rest[:, 1:], grey[:, :-1], grey[:, 1:]),
                         (rest[:, :-1], grown[:, 1:], grey[:, :-1], grey[:, 1:]),
                         (grown[:-1, :], rest[1:, :], grey[:-1, :], grey[1:, :]),
                         (rest[:-1, :], grown[1:, :], grey[:-1, :], grey[1:, :])):
        across = a & b
        pairs += int(across.sum())
        steps += int((np.abs(ga - gb)[across] >= step).sum())
    if 2 * steps < pairs:
        return None
    return grown


def front_extent(obj: SeenObject, occluder: SeenObject, image: np.ndarray, step: float,
                 ground_max: float, seeds: np.ndarray | None = None,
                 own: np.ndarray | None = None) -> np.ndarray | None:
    """The pixels of ``obj`` that are the nearer ``occluder``'s edge, or None.

    The occluder's pixels within ``OCCLUDER_GAP_PX`` of the ROI's are split into its
    faces' greys (``_faces``); the face taken is the one most of ``seeds`` (the layer the
    fovea found in front) lies within ``step`` of. The extent is grown from the pixels of
    ``seeds`` beside occluder pixels of that face and within ``step`` of its grey, through
    4-neighbours within ``step`` of each other (one surface's shading), never across a
    larger step (two greys that are not one surface's) nor farther than two steps from the
    face's grey. None when nothing grows or everything does, when fewer than half of the
    4-neighbour pairs across the grown part's edge within the ROI are a step (the growth
    stopped by drifting across one grey: the two greys cannot be told apart), or when the
    fovea gave most of it to the fixated object's own surface (``own``). Pixels no
    brighter than ``ground_max`` (the ground's level plus its noise: both ROIs hold some
    ground at their feet) neither seed nor grow it. Without ``seeds`` every pixel of the
    ROI may seed it.
    """
    u0, v0, u1, v1 = obj.blob.bbox
    img = np.asarray(image, np.float32)
    grey = img[v0:v1, u0:u1]
    mask = obj.blob.mask & (grey > ground_max)
    g = OCCLUDER_GAP_PX
    # The occluder's pixels around the ROI's bbox, g pixels beyond it.
    h, w = mask.shape
    occ = np.zeros((h + 2 * g, w + 2 * g), bool)
    ou0, ov0, ou1, ov1 = occluder.blob.bbox
    r0, r1 = max(v0 - g, ov0), min(v1 + g, ov1)
    c0, c1 = max(u0 - g, ou0), min(u1 + g, ou1)
    if r0 >= r1 or c0 >= c1:
        return None
    occ[r0 - v0 + g:r1 - v0 + g, c0 - u0 + g:c1 - u0 + g] = \
        occluder.blob.mask[r0 - ov0:r1 - ov0, c0 - ou0:c1 - ou0] & (img[r0:r1, c0:c1]
                                                                    > ground_max)
    around = np.zeros(occ.shape, np.float32)
    rr0, rr1 = max(v0 - g, 0), min(v1 + g, img.shape[0])
    cc0, cc1 = max(u0 - g, 0), min(u1 + g, img.shape[1])
    around[rr0 - v0 + g:rr1 - v0 + g, cc0 - u0 + g:cc1 - u0 + g] = img[rr0:rr1, cc0:cc1]
    # The occluder's face the edge continues: its pixels within g of the ROI's are split
    # into its faces' greys (``_faces``: a box's top and its front face may both meet the
    # ROI, a step apart; a stray pixel of the fixated object in the occluder's ROI is no
    # face); the one most of the layer found in the fovea (``seeds``) lies within a step
    # of.
    band = occ & (cv2.dilate(np.pad(mask, g).astype(np.uint8),
                             np.ones((2 * g + 1, 2 * g + 1), np.uint8)) > 0)
    if not band.any():
        return None
    seedable = mask if seeds is None else mask & seeds
    faces = _faces(around[band], step)
    face = max(faces, key=lambda f: int((np.abs(grey[seedable] - f) < step).sum()))
    # Seeds: those pixels beside (within g) occluder pixels of that face, their grey
    # within a step of it.
    of_face = occ & (np.abs(around - face) < step)
    start = np.zeros(mask.shape, bool)
    for r, c in zip(*np.nonzero(seedable), strict=True):
        if of_face[r:r + 2 * g + 1, c:c + 2 * g + 1].any() and abs(grey[r, c] - face) < step:
            start[r, c] = True
    grown = grown_across_greys(start, mask, grey, step, face)
    if grown is None:
        return None
    # Nor where the fovea saw the fixated object's own surface on most of it.
    if own is not None and 2 * int((grown & own).sum()) > int(grown.sum()):
        return None
    return grown


#: A face of the occluder holds at least this share of its pixels beside the fixated ROI
#: (a convex object shows at most three faces).
FACE_SHARE: float = 0.25


def _faces(greys: np.ndarray, step: float) -> list[float]:
    """The greys of the occluder's faces among ``greys`` (its pixels beside the fixated
    ROI): the two classes of the split that leaves the least spread within them (Otsu's),
    when their medians lie ``step`` or more apart and each holds at least ``FACE_SHARE``
    of the pixels, the larger first; else their median."""
    g = np.sort(np.asarray(greys, np.float64))
    n = g.size
    if n >= 2:
        k = np.arange(1, n)
        c1, c2 = np.cumsum(g), np.cumsum(g * g)
        within = (c2[k - 1] - c1[k - 1] ** 2 / k) \
            + ((c2[-1] - c2[k - 1]) - (c1[-1] - c1[k - 1]) ** 2 / (n - k))
        cut = int(k[np.argmin(within)])
        low, high = g[:cut], g[cut:]
        if (min(low.size, high.size) >= FACE_SHARE * n
                and float(np.median(high) - np.median(low)) >= step):
            return [float(np.median(x)) for x in sorted((low, high), key=lambda x: -x.size)]
    return [float(np.median(g))]


def _part(obj: SeenObject, mask: np.ndarray, depth: float, frame: StereoFrame, bg: float
          ) -> SeenObject:
    """The part ``mask`` (within ``obj``'s bbox) of a parted object, placed at ``depth``
    on the ray through its own centroid, as ``roi_finder`` places an object."""
    rows, cols = np.nonzero(mask)
    u0, v0 = obj.blob.bbox[0], obj.blob.bbox[1]
    box = (v0 + int(rows.min()), u0 + int(cols.min()), v0 + int(rows.max()) + 1,
           u0 + int(cols.max()) + 1)
    labels = np.zeros(frame.left.shape, np.int32)
    labels[v0:v0 + mask.shape[0], u0:u0 + mask.shape[1]][mask] = 1
    blob = blob_of(labels, 1, frame.left, bg, box)
    cu, cv = blob.centroid
    cam = frame.camera
    ray = np.array([(cu - cam.width / 2.0) / cam.focal_px, (cv - cam.height / 2.0) / cam.focal_px,
                    1.0])
    position = as_point(frame.left_pose.position + frame.left_pose.rotation @ (ray * depth))
    ur, vr, _ = project_point(cam, frame.right_pose, position)
    return SeenObject(blob=blob, depth=float(depth), position=position, centre_px=(cu, cv),
                      right_px=(ur, vr), width_px=float(blob.width_px), cut=obj.cut,
                      cost=obj.cost)


@dataclass(frozen=True)
class _Measured:
    """What the first pass of ``Perception.process`` measured of a ROI.

    Attributes:
        rim: Its samples along its own edge.
        intensity, texture: Equations 1-2.
        magnification: Its size in the right retina over its size in the left (the
            ratio of its depths along the two optical axes).
    """

    rim: Rim
    intensity: np.ndarray
    texture: np.ndarray
    magnification: float


def _check_frame(frame: StereoFrame) -> None:
    shape = (frame.camera.height, frame.camera.width)
    for name in ("left", "right"):
        img = getattr(frame, name)
        if not isinstance(img, np.ndarray) or img.shape != shape:
            got = getattr(img, "shape", type(img).__name__)
            raise MessageError(f"StereoFrame.{name}: shape {got}, camera says {shape}")
        if not np.isfinite(img).all():
            raise MessageError(f"StereoFrame.{name}: holds NaN or infinite pixels")


def _near_border(bbox: tuple[int, int, int, int], size: tuple[int, int], margin: int) -> bool:
    u0, v0, u1, v1 = bbox
    return u0 < margin or v0 < margin or u1 > size[0] - margin or v1 > size[1] - margin
