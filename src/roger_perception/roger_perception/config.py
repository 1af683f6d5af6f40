"""Configuration of the perception core: one frozen dataclass, validated on construction.

Every field is documented in docs/perception.md, with the reason for its default.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from roger_common.errors import ConfigError
from roger_common.types import DEFAULT_FEATURE_MODE, FeatureMode


def _fail(name: str, value: object, need: str) -> ConfigError:
    return ConfigError(f"PerceptionConfig.{name}={value!r}: {need}")


@dataclass(frozen=True)
class PerceptionConfig:
    """Parameters of the visual buffer, the ROIs, the features and the activation.

    Attributes:
        log_sigmas: Gaussian sigmas (pixels) of the LoG at the resolutions k = 1, 2, 3,
            strictly increasing.
        kernel_radius_sigmas: Kernel half-width in sigmas; the kernel diameter of
            resolution k is ``2 * ceil(kernel_radius_sigmas * sigma_k) + 1`` pixels.
        samples_m: M, the number of samples per ROI and resolution (equations 1-3),
            independent of the ROI's size.
        contrast_max: Edge contrast against the ground that makes I^(k) reach 1: G_max^(k)
            is the peak response of kernel k to a straight edge of this contrast.
        vicinity_sigmas: Radius, in sigmas of resolution k (at least 1 px), of the
            neighbourhood in which a sample takes the largest LoG magnitude.
        s_max_m: s_max of equation 3, metres: the largest depth relief within a ROI. Each
            sample's disparity relative to the ROI's is turned into depth relief with the
            stereo geometry, so that S does not fall with distance as 1 / Z^4.
        stereo_search_px: The correlation tries shifts of -n..n pixels along the
            epipolar line around the disparity of the ROI's centroids.
        match_window_sigmas: Half-size, in sigmas of resolution k (at least 1 px), of the
            correlation window used to measure disparity.
        stereo_smoothness: Weight of the prior that pulls an ambiguous disparity to the
            ROI's mean disparity (cost += smoothness * t^2 * local energy).
        size_view_distance_m: D_max of equation 4 is the width of the retina's field of
            view at this distance from the eyes, metres: the nearest an object can stand in
            view (world files keep x >= 0.3 m; the eyes are 0.8 m above the ground), so no
            object that fits the retina whole reads D above 1.
        w_max_kg: W_max of equation 5, the heaviest weight an arm can lift, kilograms.
        haptic_radius_m: A haptic reading belongs to a ROI whose position lies within this
            distance of the contact point.
        mapped_radius_m: A ROI is mapped when a mapped position lies within this distance.
        fg_threshold: Retinal intensity above the background level that is an object.
        dim_sigmas: A second, fainter foreground (``segmentation.dim_foreground``): after a
            5x5 median filter, pixels this many of the ground's own noise (measured on this
            retina) above the ground's median, 2 px or more from the ``fg_threshold``
            foreground, in parts of at least ``min_roi_pixels``: objects darker than
            ``fg_threshold`` above the ground (grey 25 renders 0.02 above it). 0: none.
        window_sigmas: A ROI's window (``Roi.bbox``, the attention window) is the box of
            its pixels that stand this many of the ground's own noise above the ground
            after a 3x3 median filter (``segmentation.window_boxes``): the object, not the
            ground seam between it and a neighbour that the watershed gave it. 0: the
            box of all the ROI's pixels.
        grad_threshold: Intensity gradient (per pixel, after a 1 px Gaussian) below which
            a foreground pixel is flat and may seed a watershed fragment; edges between
            objects or faces are steeper.
        sweep_near_m, sweep_far_m: Depth range (m, along the left optical axis) of the
            plane sweep that measures the depth of fragments and ROIs.
        sweep_step_px: Epipolar shift (pixels) between two depth hypotheses.
        match_cost_trunc: Truncation of the per-pixel matching cost |L - R| (intensity).
        occlusion_band_px: Pixels this close to another fragment (or ROI) are left out of
            its depth estimate (occlusion changes them between the eyes).
        min_depth_pixels: An object with fewer samples away from other objects has its
            depth measured on all its samples; the leftmost or rightmost edge of an
            object (its position) needs half this many to be measured.
        min_depth_rise: An object's edge whose mean cost rises less than this two
            hypotheses away from its minimum is ambiguous and not used for its position.
        max_match_cost: A ROI whose best mean matching cost exceeds this is not seen by
            the right eye (occluded or out of its view) and is dropped.
        min_roi_pixels: Smaller connected regions are noise, not ROIs.
        border_margin_px: When > 0, ROIs that come within this many pixels of the image
            edge in either retina are dropped (their position and size are biased by the
            cut); 0 keeps them, so that objects at the periphery can attract attention.
        epipolar_tol_px: Largest distance of a right ROI's centroid from the left one's
            epipolar line for the two to be matched.
        max_ray_gap_m: Largest miss distance of the two triangulated rays.
        max_area_ratio: Largest ratio of the areas of two matched ROIs.
        max_intensity_diff: Largest difference of mean intensity of two matched ROIs.
        size_norm: Retinal share (of the image area) at which the size term saturates.
        weight_size, weight_intensity, weight_motion, weight_tactile, weight_unmapped:
            Weights of the pre-attentive activation terms (non-negative, not all zero).
        cv_threads: OpenCV worker threads (process-wide, set when a Perception is built;
            >= 1). One by default: between calls OpenCV's workers busy-wait
            (``sched_yield``), which on a 2-core machine takes a core from the other
            nodes of the graph, and the filters here are too small to gain from threads
            (docs/performance.md). Values never depend on it.
        min_rim_share: A ROI whose outer contour is its own edge against the ground on
            less than this share (the rest borders another ROI or the retina's edge) has
            I, T, S and D unknown: they would measure the occluder or the cut, not the
            object.
        min_stereo_samples: S^(k) is unknown when fewer of the M samples were matched
            (a sample whose disparity search ends at its range, or whose relief exceeds
            the object's size, is a failed match).
        depth_sigmas: Margin, in standard errors of the robot's own matching noise, by
            which a pixel's window must match one of two depths better than the other
            to be taken for that depth (where a fragment holding two objects is cut).
        notch_px: Deepest concave notch of ground (pixels, from the convex hull) the
            union of two fragments of one object may hold: the image of a convex shape
            is convex up to digitisation.
        binocular_split: Split a left-retina object whose fragments (or a fragment whose
            parts, at different depths) fall, at its depth, on different objects of the
            right retina (objects one behind the other whose outlines line up in the
            left eye; ``roger_perception.binocular``).
        behind_split: Cut off the top of an object's silhouette that the plane sweep
            places farther behind the object's centre than half its width, at
            ``depth_sigmas`` standard errors (an object in line behind a taller one, seen
            above it; ``roger_perception.behind``). Off by default: it costs a merge in
            a look at two shipped worlds and 4-6 % of perception's time, for visits on
            worlds with such objects (docs/perception.md, step 9).
        fovea_layers: In the extended mode, part a fixated ROI where the two foveae of a
            visual improvement see a layer behind the fixated object (an object in line
            behind it, 5-30 cm farther, that the retinas cannot part), and keep the layer
            by position to part the ROI in later frames too
            (``roger_perception.fovea_layers``). Needs the simulator's
            right fovea (its ``fovea_stereo``). The paper mode never parts a ROI so.
        motion_threshold: Change of a pixel's smoothed intensity, after Roger's own eye and
            neck motion is compensated, that counts as visual motion: half of
            ``fg_threshold``, since an object is at least that much brighter than the
            ground, so an object appearing on bare ground changes every pixel by more.
        motion_blur_px: Sigma (pixels) of the Gaussian that smooths the left retina before
            motion is measured (pixel noise, sub-pixel re-projection error); 0: none.
        motion_min_evidence: Share of a ROI's pixels the previous left eye must have seen
            for its motion to be measured; below it the motion is 0 (no evidence).
        features: Feature mode: "paper" (the eleven features of equations 1-5) or
            "extended" (those, then the shape evidence of ``shape.py``).
        light_direction: Direction towards the scene's one light, robot frame (any
            length): what the robot knows of its light, as it knows its camera. The
            extended mode's AS (``shape.sphere_albedo``) divides the shading by it. The
            runner sets it from the world file's ``light_direction``.
        light_ambient: The light's ambient coefficient (the simulator's ``light_ambient``).
        light_diffuse: The light's diffuse coefficient (the simulator's ``light_diffuse``).
    """

    log_sigmas: tuple[float, float, float] = (1.0, 1.5, 2.2)
    kernel_radius_sigmas: float = 3.0
    samples_m: int = 32
    contrast_max: float = 0.5
    vicinity_sigmas: float = 1.0
    s_max_m: float = 0.1
    stereo_search_px: int = 3
    match_window_sigmas: float = 2.0
    stereo_smoothness: float = 0.02
    size_view_distance_m: float = 0.77
    w_max_kg: float = 2.0
    haptic_radius_m: float = 0.08
    mapped_radius_m: float = 0.08
    fg_threshold: float = 0.06
    dim_sigmas: float = 5.0
    window_sigmas: float = 3.0
    grad_threshold: float = 0.012
    sweep_near_m: float = 0.4
    sweep_far_m: float = 3.5
    sweep_step_px: float = 1.0
    match_cost_trunc: float = 0.08
    occlusion_band_px: int = 3
    min_depth_pixels: int = 10
    min_depth_rise: float = 0.002
    max_match_cost: float = 0.04
    min_roi_pixels: int = 12
    border_margin_px: int = 0
    epipolar_tol_px: float = 4.0
    max_ray_gap_m: float = 0.05
    max_area_ratio: float = 2.5
    max_intensity_diff: float = 0.15
    size_norm: float = 0.05
    weight_size: float = 1.0
    weight_intensity: float = 1.0
    weight_motion: float = 1.0
    weight_tactile: float = 1.0
    weight_unmapped: float = 2.0
    cv_threads: int = 1
    min_rim_share: float = 0.5
    min_stereo_samples: int = 8
    depth_sigmas: float = 3.0
    notch_px: float = 1.5
    binocular_split: bool = True
    behind_split: bool = False
    fovea_layers: bool = True
    motion_threshold: float = 0.03
    motion_blur_px: float = 1.0
    motion_min_evidence: float = 0.5
    features: str = DEFAULT_FEATURE_MODE.value
    light_direction: tuple[float, float, float] = (1.0, 0.5, 1.0)
    light_ambient: float = 0.6
    light_diffuse: float = 0.35

    def __post_init__(self) -> None:
        try:
            object.__setattr__(self, "features", FeatureMode.parse(self.features).value)
        except (ValueError, TypeError) as exc:
            raise _fail("features", self.features, str(exc)) from None
        light = tuple(self.light_direction)
        if (len(light) != 3 or not all(_finite(c) for c in light)
                or math.hypot(*light) <= 1e-9):
            raise _fail("light_direction", self.light_direction,
                        "need three finite numbers, not all 0 (towards the light)")
        object.__setattr__(self, "light_direction", tuple(float(c) for c in light))
        for name in ("light_ambient", "light_diffuse"):
            value = getattr(self, name)
            if not _finite(value) or value < 0:
                raise _fail(name, value, "need a finite number >= 0")
        if self.light_ambient + self.light_diffuse <= 0:
            raise _fail("light_diffuse", self.light_diffuse,
                        "need light_ambient + light_diffuse > 0")
        sig = tuple(self.log_sigmas)
        if len(sig) != 3 or not all(_finite(s) and s > 0 for s in sig):
            raise _fail("log_sigmas", self.log_sigmas, "need three positive sigmas (pixels)")
        if not (sig[0] < sig[1] < sig[2]):
            raise _fail("log_sigmas", self.log_sigmas, "need strictly increasing sigmas")
        object.__setattr__(self, "log_sigmas", tuple(float(s) for s in sig))
        if not isinstance(self.samples_m, int) or self.samples_m < 2:
            raise _fail("samples_m", self.samples_m, "need an integer >= 2")
        if not isinstance(self.stereo_search_px, int) or self.stereo_search_px < 1:
            raise _fail("stereo_search_px", self.stereo_search_px, "need an integer >= 1")
        if not isinstance(self.border_margin_px, int) or self.border_margin_px < 0:
            raise _fail("border_margin_px", self.border_margin_px, "need an integer >= 0")
        for name in ("occlusion_band_px", "min_depth_pixels"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 0:
                raise _fail(name, value, "need an integer >= 0")
        if not (_finite(self.sweep_near_m) and _finite(self.sweep_far_m)
                and 0 < self.sweep_near_m < self.sweep_far_m):
            raise _fail("sweep_far_m", self.sweep_far_m,
                        f"need 0 < sweep_near_m ({self.sweep_near_m!r}) < sweep_far_m")
        if (not isinstance(self.cv_threads, int) or isinstance(self.cv_threads, bool)
                or self.cv_threads < 1):
            raise _fail("cv_threads", self.cv_threads, "need an integer >= 1")
        if not (_finite(self.min_rim_share) and 0.0 <= self.min_rim_share <= 1.0):
            raise _fail("min_rim_share", self.min_rim_share, "need a share in [0, 1]")
        if (not isinstance(self.min_stereo_samples, int)
                or isinstance(self.min_stereo_samples, bool)
                or not 1 <= self.min_stereo_samples <= self.samples_m):
            raise _fail("min_stereo_samples", self.min_stereo_samples,
                        "need an integer in [1, samples_m]")
        if not isinstance(self.min_roi_pixels, int) or self.min_roi_pixels < 1:
            raise _fail("min_roi_pixels", self.min_roi_pixels, "need an integer >= 1")
        positive = (
            "kernel_radius_sigmas", "contrast_max", "vicinity_sigmas", "s_max_m",
            "match_window_sigmas", "size_view_distance_m", "w_max_kg", "haptic_radius_m",
            "mapped_radius_m",
            "fg_threshold", "epipolar_tol_px", "max_ray_gap_m", "max_intensity_diff",
            "size_norm", "grad_threshold", "sweep_step_px",
            "match_cost_trunc", "max_match_cost", "depth_sigmas", "notch_px",
        )
        for name in positive:
            value = getattr(self, name)
            if not _finite(value) or value <= 0:
                raise _fail(name, value, "need a finite number > 0")
        if self.kernel_radius_sigmas < 2.0:
            raise _fail("kernel_radius_sigmas", self.kernel_radius_sigmas,
                        "need >= 2 so that the kernel holds its negative ring")
        if self.max_area_ratio < 1.0 or not _finite(self.max_area_ratio):
            raise _fail("max_area_ratio", self.max_area_ratio, "need a finite number >= 1")
        if self.fg_threshold >= 1.0:
            raise _fail("fg_threshold", self.fg_threshold, "need < 1 (images are in [0, 1])")
        non_negative = ("stereo_smoothness", "min_depth_rise", "motion_blur_px", "dim_sigmas",
                        "window_sigmas",
                        *self.weight_names())
        for name in non_negative:
            value = getattr(self, name)
            if not _finite(value) or value < 0:
                raise _fail(name, value, "need a finite number >= 0")
        if not (_finite(self.motion_threshold) and 0 < self.motion_threshold < 1):
            raise _fail("motion_threshold", self.motion_threshold, "need 0 < value < 1")
        if not (_finite(self.motion_min_evidence) and 0 < self.motion_min_evidence <= 1):
            raise _fail("motion_min_evidence", self.motion_min_evidence,
                        "need 0 < value <= 1")
        if sum(self.activation_weights()) <= 0:
            raise _fail("weight_unmapped", self.weight_unmapped,
                        "the activation weights must not all be zero")

    @staticmethod
    def weight_names() -> tuple[str, ...]:
        """Names of the activation weight fields, in the order of activation_weights()."""
        return ("weight_size", "weight_intensity", "weight_motion", "weight_tactile",
                "weight_unmapped")

    def activation_weights(self) -> tuple[float, ...]:
        """Weights of (size, intensity, motion, tactile, unmapped)."""
        return tuple(float(getattr(self, n)) for n in self.weight_names())

    @property
    def feature_mode(self) -> FeatureMode:
        """``features`` as the enum."""
        return FeatureMode(self.features)

    def kernel_sizes(self) -> tuple[int, int, int]:
        """LoG kernel diameters (pixels, odd) of the resolutions k = 1, 2, 3."""
        s1, s2, s3 = (kernel_size(s, self.kernel_radius_sigmas) for s in self.log_sigmas)
        return s1, s2, s3



def kernel_size(sigma: float, radius_sigmas: float = 3.0) -> int:
    """Odd kernel diameter that holds ``radius_sigmas`` sigmas on each side of the centre."""
    return 2 * math.ceil(radius_sigmas * sigma) + 1


def _finite(value: object) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(
        value)
