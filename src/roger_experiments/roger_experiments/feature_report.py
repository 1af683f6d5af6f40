"""``roger features``: do Roger's features repeat? (issue 15, a measurement, not a test)

The robot looks at a world the way it does in a run, without the memory or a policy:

1. the initial scan (``AttentionConfig.home_targets``): every ROI of every look;
2. for every place the scan settled in the spatial map (the controller's own association),
   an attention shift onto it, a visual improvement and a haptic improvement (the weight);
3. a shift back onto each place after all of them were visited;
4. (``noise_looks`` > 0) that many more shifts onto each place, one after another: the same
   fixation with fresh pixel noise, the robot's own sensor noise. These looks are kept
   apart from the statistics above.

Each ROI of each frame is one *look*. The simulator's label images say (for scoring only)
which object a ROI shows and how pure it is; the robot never sees them. Per feature the
report gives the within-object spread (the pooled standard deviation of the looks of one
object around their mean), the spread between categories (the standard deviation of the
category means) and their ratio, and the spread between copies of one category standing at
other places (view dependence: what a repeat of a category must be recognised through);
over all the features, the distance between two looks
of one object against the distance between the two nearest categories (RMS over the
features known in both, the memory's distance); the ROI purity and merges; and where the
ROIs are placed against the footprint centres (positions). From the looks of step 4, per
feature the spread of one fixation's looks (sensor noise alone) and the *ceiling*: the
spread between categories over it, the ratio the feature would reach if one object's looks
differed by sensor noise alone and nothing else (view, shading, segmentation). A feature
whose ceiling is under the target cannot reach it by any change of the view it is taken
from; only a less noisy measurement (or sensor) can lift it.

The features are those of the looks' mode (``roger_common.types.FeatureMode``): the paper's
eleven, or those and the extended shape features (``feature_names``). A feature that no
look measured (the touch features without a haptic improvement) is reported unknown, NaN
in features.json.
"""

from __future__ import annotations

import csv
import itertools
import json
import math
import warnings
from collections import defaultdict
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from roger_attention.config import AttentionConfig
from roger_attention.spatial_map import SpatialMap
from roger_common.atomic import atomic_write_bytes
from roger_common.errors import ConfigError
from roger_common.types import (
    FEATURE_NAMES,
    SHAPE_FEATURE_NAMES,
    WEIGHT_INDEX,
    Action,
    FeatureMode,
    Goal,
    Roi,
    StereoFrame,
    WorldSpec,
    feature_names,
    mode_of_dim,
)
from roger_experiments.core_loop import with_light
from roger_memory.calibration import rms_z
from roger_memory.config import MemoryConfig
from roger_perception.config import PerceptionConfig
from roger_perception.perception import Perception
from roger_sim.config import SimConfig
from roger_sim.simulator import Simulator

#: Stages of a look, in the order the robot takes them.
STAGES: tuple[str, ...] = ("scan", "shift", "visual", "haptic", "back")
#: Stages that look at the focus (what the memory is asked about).
FOCUS_STAGES: tuple[str, ...] = ("shift", "visual", "haptic", "back")
#: Stage of the repeated looks at one fixation (step 4): sensor noise, not in the spreads.
NOISE_STAGE = "noise"
#: A ROI showing an object on less than this share of its pixels is impure (not a look at
#: one object); two objects each on at least MERGE_SHARE of a ROI's pixels are merged.
PURE_SHARE = 0.8
MERGE_SHARE = 0.15
#: The target of the issue: every feature that enters the memory's decision separates
#: categories at least this many times better than one object's looks scatter.
RATIO_TARGET = 2.0


@dataclass(frozen=True)
class Look:
    """One ROI of one frame.

    Attributes:
        stage: One of STAGES.
        gaze: Number of the frame (0 for the first look of the scan).
        focus: For a focus stage, True when the ROI is the one nearest the fixation.
        obj: The object most of its pixels show (ground truth; None for none).
        purity: Share of its pixels on that object.
        merged: Objects covering at least MERGE_SHARE of its pixels each (2+: a merge).
        roi: The ROI as perception gave it.
        place: Index of the spatial-map place the gaze aimed at (-1 for the scan).
    """

    stage: str
    gaze: int
    focus: bool
    obj: str | None
    purity: float
    merged: tuple[str, ...]
    roi: Roi
    place: int = -1


@dataclass
class LookLog:
    """Every look of a world, and what it took.

    Attributes:
        mode: Feature mode of the looks (``collect_looks`` sets it); None: the length of
            the looks' feature vectors says (``looks_mode``).
    """

    world: WorldSpec
    looks: list[Look] = field(default_factory=list)
    frames: int = 0
    mode: FeatureMode | None = None

    @property
    def feature_mode(self) -> FeatureMode:
        """The looks' feature mode."""
        return self.mode if self.mode is not None else looks_mode(self.looks)


def looks_mode(looks: Iterable[Look]) -> FeatureMode:
    """The feature mode of ``looks``, from the length of their feature vectors.

    Raises:
        ValueError: The looks' vectors differ in length or have no mode's length.
    """
    dims = {len(lk.roi.features) for lk in looks}
    if len(dims) > 1:
        raise ValueError(f"looks of several feature lengths {sorted(dims)}: one mode a report")
    # No look: nothing to lay out; the paper's eleven keep the tables' old shape.
    return mode_of_dim(dims.pop()) if dims else FeatureMode.PAPER


def _layout(looks: Iterable[Look], names: tuple[str, ...] | None) -> tuple[str, ...]:
    return names if names is not None else feature_names(looks_mode(looks))


def label_shares(frame: StereoFrame, roi_labels: np.ndarray, roi_id: int
                  ) -> list[tuple[str, float]]:
    """(object, share of the ROI's pixels) for the objects under a ROI, largest first."""
    if frame.left_labels is None:
        return []
    under = frame.left_labels[roi_labels == roi_id + 1]
    if under.size == 0:
        return []
    counts = np.bincount(under[under >= 0], minlength=len(frame.label_names))
    order = np.argsort(-counts)
    return [(frame.label_names[i], counts[i] / under.size) for i in order if counts[i] > 0]


def collect_looks(world: WorldSpec, seed: int = 0, sim_config: SimConfig | None = None,
                  perception_config: PerceptionConfig | None = None,
                  attention_config: AttentionConfig | None = None,
                  noise_looks: int = 0) -> LookLog:
    """Let the robot look at ``world`` (module docstring) and keep every look.

    Args:
        noise_looks: Shifts onto each place after everything else (step 4): the same
            fixation with fresh pixel noise; 0 for none. They come last, so the looks of
            steps 1-3 are the same with and without them.
    """
    if noise_looks < 0:
        raise ConfigError(f"noise_looks (roger features --noise-looks) must be >= 0, got "
                          f"{noise_looks}")
    att = attention_config or AttentionConfig()
    sim_config = sim_config or SimConfig()
    sim = Simulator(world, sim_config, seed=seed)
    perception_config = with_light(perception_config or PerceptionConfig(), world, sim_config)
    perception = Perception(perception_config)
    smap = SpatialMap(att.spatial_map)
    log = LookLog(world, mode=perception_config.feature_mode)
    goal_id = 0

    def look(action: Action, target: tuple[float, float, float], stage: str,
             place: int = -1) -> list[Roi]:
        nonlocal goal_id
        goal_id += 1
        _, frame = sim.run_goal(Goal(goal_id, action, target))
        rois = perception.process(frame, smap.mapped_positions())
        smap.update(rois, frame.stamp)
        near = min(rois, key=lambda r: math.dist(r.position[:2], target[:2]), default=None)
        if near is not None and math.dist(near.position[:2], target[:2]) > \
                att.spatial_map.association_radius:
            near = None
        for roi in rois:
            shares = label_shares(frame, perception.last_roi_labels, roi.roi_id)
            obj, purity = shares[0] if shares else (None, 0.0)
            merged = tuple(o for o, s in shares if s >= MERGE_SHARE)
            log.looks.append(Look(stage, log.frames, roi is near and stage != "scan", obj,
                                  float(purity), merged, roi, place))
        log.frames += 1
        return rois

    try:
        for target in att.scan_targets:
            look(Action.ATTENTION_SHIFT, target, "scan")
        places = [e.position for e in smap]
        for i, place in enumerate(places):
            look(Action.ATTENTION_SHIFT, place, "shift", i)
            look(Action.VISUAL_IMPROVEMENT, place, "visual", i)
            look(Action.HAPTIC_IMPROVEMENT, place, "haptic", i)
        for i, place in enumerate(places):
            look(Action.ATTENTION_SHIFT, place, "back", i)
        for i, place in enumerate(places):
            for _ in range(noise_looks):
                look(Action.ATTENTION_SHIFT, place, NOISE_STAGE, i)
    finally:
        sim.close()
    return log


def _rms(a: np.ndarray, b: np.ndarray, ka: np.ndarray, kb: np.ndarray) -> float:
    k = ka & kb
    return float(np.sqrt(np.mean((a[k] - b[k]) ** 2))) if k.any() else math.nan


def _stacked(looks: list[Look]) -> tuple[np.ndarray, np.ndarray]:
    """The features (float64) and known masks of ``looks``, one row each."""
    return (np.stack([lk.roi.features for lk in looks]).astype(np.float64),
            np.stack([lk.roi.known for lk in looks]))


def _deviations(x: np.ndarray, k: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per feature, of the looks (x, k) of one group: the mean over the looks that
    measured it (NaN where none did), the sum of their squared deviations from it, and
    their degrees of freedom (looks that measured it minus one)."""
    cnt = k.sum(axis=0)
    mean = np.where(cnt > 0, (x * k).sum(axis=0) / np.maximum(cnt, 1), np.nan)
    sq = (np.where(k, x - mean, 0.0) ** 2).sum(axis=0)
    return mean, sq, np.maximum(cnt - 1, 0)


def feature_stats(looks: Iterable[Look], world: WorldSpec,
                  names: tuple[str, ...] | None = None) -> dict[str, Any]:
    """Within-object and between-category spread of every feature, look distances.

    Only pure looks (PURE_SHARE) of an object count. A feature no pure look measured has
    every spread and ratio NaN (unknown, not "no spread").

    Args:
        names: The features' layout (None: that of the looks' mode).
    """
    looks = list(looks)
    names = _layout(looks, names)
    category = {o.name: o.category() for o in world.objects}
    by_obj: dict[str, list[Look]] = defaultdict(list)
    for lk in looks:
        if lk.obj is not None and lk.purity >= PURE_SHARE:
            by_obj[lk.obj].append(lk)
    n = len(names)
    measured = np.zeros(n, bool)
    within_sq, within_n = np.zeros(n), np.zeros(n)
    obj_mean: dict[str, np.ndarray] = {}
    obj_known: dict[str, np.ndarray] = {}
    for name, lks in by_obj.items():
        x, k = _stacked(lks)
        mean, sq, dof = _deviations(x, k)
        obj_mean[name], obj_known[name] = mean, k.sum(axis=0) > 0
        measured |= obj_known[name]
        within_sq += sq
        within_n += dof
    within = np.where(measured, np.sqrt(within_sq / np.maximum(within_n, 1)), np.nan)
    cats: dict[Any, list[str]] = defaultdict(list)
    for name in obj_mean:
        cats[category[name]].append(name)
    with warnings.catch_warnings():
        # A feature no copy of a category measured has a NaN mean (an empty slice).
        warnings.simplefilter("ignore", RuntimeWarning)
        cat_mean = {c: np.nanmean(np.stack([obj_mean[o] for o in objs]), axis=0)
                    for c, objs in cats.items()}
        means = np.stack(list(cat_mean.values())) if cat_mean else np.zeros((0, n))
        between = np.nanstd(means, axis=0, ddof=1) if len(means) > 1 else np.full(n, np.nan)
    copies, copy_pairs = _copy_spread(cats, obj_mean, obj_known, cat_mean, n)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = between / within
        ratio_copies = between / copies
    pairs = []
    for name, lks in by_obj.items():
        for a, b in itertools.combinations(lks, 2):
            pairs.append(_rms(a.roi.features, b.roi.features, a.roi.known, b.roi.known))
    cat_d = [(float(np.sqrt(np.nanmean((cat_mean[a] - cat_mean[b]) ** 2))), a, b)
             for a, b in itertools.combinations(cat_mean, 2)]
    nearest = min(cat_d) if cat_d else (math.nan, None, None)
    pairs_a = np.asarray([p for p in pairs if math.isfinite(p)])
    return {
        "features": list(names),
        "within": within.tolist(), "between": between.tolist(), "ratio": ratio.tolist(),
        "objects": len(by_obj), "categories": len(cat_mean),
        "looks": int(sum(len(v) for v in by_obj.values())),
        "look_distance_median": float(np.median(pairs_a)) if pairs_a.size else math.nan,
        "look_distance_p90": float(np.percentile(pairs_a, 90)) if pairs_a.size else math.nan,
        "nearest_categories_distance": nearest[0],
        "nearest_categories": [list(nearest[1]) if nearest[1] else None,
                               list(nearest[2]) if nearest[2] else None],
        "copies": copies.tolist(), "ratio_copies": ratio_copies.tolist(),
        "copy_distance_median": float(np.median(copy_pairs)) if copy_pairs.size
        else math.nan,
    }


def _copy_spread(cats: dict[Any, list[str]], obj_mean: dict[str, np.ndarray],
                 obj_known: dict[str, np.ndarray], cat_mean: dict[Any, np.ndarray], n: int
                 ) -> tuple[np.ndarray, np.ndarray]:
    """How far copies of one category, standing at other places, read apart.

    Per feature, the pooled standard deviation of the object means of each category
    around the category's mean (degrees of freedom: copies seen minus one per category);
    NaN when no category had two copies seen. And the RMS distance (features known in
    both) between the means of every two copies of one category. A copy at another place
    is seen at another bearing, distance and yaw: where this spread reaches the spread
    between categories, no threshold on that feature tells "another copy" from "another
    category" (docs/perception.md, "View dependence").
    """
    sq, dof = np.zeros(n), np.zeros(n)
    pairs = []
    for c, names in cats.items():
        if len(names) < 2:
            continue
        x = np.stack([obj_mean[o] for o in names])
        k = np.stack([obj_known[o] for o in names])
        dev = np.where(k, x - cat_mean[c], 0.0)
        sq += (dev * dev).sum(axis=0)
        dof += np.maximum(k.sum(axis=0) - 1, 0)
        for a, b in itertools.combinations(names, 2):
            pairs.append(_rms(obj_mean[a], obj_mean[b], obj_known[a], obj_known[b]))
    with np.errstate(divide="ignore", invalid="ignore"):
        spread = np.where(dof > 0, np.sqrt(sq / np.maximum(dof, 1)), np.nan)
    arr = np.asarray([p for p in pairs if math.isfinite(p)])
    return spread, arr


def noise_stats(looks: Iterable[Look], between: Iterable[float]) -> dict[str, Any]:
    """Sensor noise: the spread of the looks at the focus of one fixation (step 4).

    The looks of one place that show its object (the object most of the place's focus
    looks show), purely, are one group; per feature, the pooled standard deviation of the
    groups around their means (degrees of freedom: looks that measured it minus one per
    group), and the ceiling ``between / sd``.

    Args:
        looks: Looks of the NOISE_STAGE (others are ignored).
        between: The spread between categories per feature (``feature_stats``); its
            length gives the features' mode.
    """
    between = np.asarray(list(between), float)
    names = feature_names(mode_of_dim(len(between)))
    by_place: dict[int, list[Look]] = defaultdict(list)
    for lk in looks:
        if lk.stage == NOISE_STAGE and lk.focus and lk.obj is not None \
                and lk.purity >= PURE_SHARE:
            by_place[lk.place].append(lk)
    n = len(names)
    sq, dof = np.zeros(n), np.zeros(n)
    visits = 0
    for lks in by_place.values():
        objs = [lk.obj for lk in lks]
        main = max(set(objs), key=objs.count)
        group = [lk for lk in lks if lk.obj == main]
        if len(group) < 2:
            continue
        visits += 1
        _, group_sq, group_dof = _deviations(*_stacked(group))
        sq += group_sq
        dof += group_dof
    sd = np.where(dof > 0, np.sqrt(sq / np.maximum(dof, 1)), np.nan)
    with np.errstate(divide="ignore", invalid="ignore"):
        ceiling = between / sd
    return {"features": list(names), "visits": visits, "sd": sd.tolist(),
            "ceiling": ceiling.tolist()}


def memory_separability(looks: Iterable[Look], world: WorldSpec,
                        config: MemoryConfig | None = None) -> dict[str, Any]:
    """Can the memory's own distance tell this world's categories apart at all?

    The looks a final trial sees: looks at the focus that show one object, with W known
    (after the haptic improvement). The memory compares a look with the looks an address
    holds, and an address refined by a category's copies holds theirs (docs/memory.md), so
    per object: the memory's distance (weighted RMS z over the common features, calibrated
    scales and weights: ``roger_memory.calibration.rms_z``) of each of its looks to the
    nearest look of any object of another category, and to the nearest look of another
    copy of its own category; the median over its looks, against the acceptance distance
    tau. An object nearer than tau to another category is taken for it more often than
    not, by any rule that accepts a repeat at tau; one farther than tau from its own
    copies is stored again more often than not. Where both happen in one world, no one
    threshold on these features serves both precisions. ``closest`` is the smallest
    distance to another category, with the share of the pairs of one object's looks and of
    the objects' own-copy distances beyond it: what a threshold that parted them would
    call novel.

    Args:
        config: The memory's configuration (None: the calibration of the looks' mode).

    Raises:
        ConfigError: ``config`` is of another feature mode than the looks.
    """
    looks = list(looks)
    mode = looks_mode(looks)
    cfg = config or MemoryConfig.for_mode(mode)
    if looks and cfg.feature_mode is not mode:
        raise ConfigError(f"memory features {cfg.features!r} against looks of the "
                          f"{mode.value} mode: give the memory the looks' mode")
    scale, weight = np.asarray(cfg.feature_scale), np.asarray(cfg.feature_weight)
    category = {o.name: o.category() for o in world.objects}
    by_obj: dict[str, list[Look]] = defaultdict(list)
    for lk in looks:
        # Every look at one object (no second one on MERGE_SHARE of its pixels), however
        # much ground it shows: the memory is asked about those too. PURE_SHARE, which
        # counts ground pixels as impure, would leave out a sphere's or a cylinder's
        # looks (a disc around a round silhouette: purity 0.72-0.80 on random 233).
        if (lk.focus and lk.stage != NOISE_STAGE and lk.obj is not None
                and len(lk.merged) <= 1 and lk.roi.known[WEIGHT_INDEX]):
            by_obj[lk.obj].append(lk)

    arrays = {name: _stacked(lks) for name, lks in by_obj.items()}

    def dist(a: str, b: str) -> np.ndarray:
        """(looks of a, looks of b) distances of every look of a to every look of b."""
        (xa, ka), (xb, kb) = arrays[a], arrays[b]
        delta = (xa[:, None, :] - xb[None, :, :]).reshape(-1, xa.shape[1])
        common = (ka[:, None, :] & kb[None, :, :]).reshape(-1, ka.shape[1])
        return rms_z(delta, common, scale, weight).reshape(len(xa), len(xb))

    tau = cfg.identify_distance
    confused, split, own_d, other_d = [], [], [], []
    repeats = []
    for name, lks in sorted(by_obj.items()):
        if len(lks) > 1:
            repeats.append(dist(name, name)[np.triu_indices(len(lks), 1)])
        others = [o for o in by_obj if category.get(o) != category.get(name)]
        copies = [o for o in by_obj if o != name and category.get(o) == category.get(name)]
        if others:
            near = np.stack([dist(name, o).min(axis=1) for o in others])
            best = near.min(axis=0)
            d = float(np.median(best))
            # The object of another category whose looks are nearest most often.
            which = others[int(np.bincount(near.argmin(axis=0)).argmax())]
            other_d.append(d)
            if d < tau:
                confused.append([name, which, d])
        if copies:
            d = float(np.median(np.min([dist(name, o).min(axis=1) for o in copies], axis=0)))
            own_d.append(d)
            if d > tau:
                split.append([name, d])
    rep = np.concatenate(repeats) if repeats else np.empty(0)
    own = np.asarray(own_d)
    closest: dict[str, Any] = {}
    if other_d:
        d_min = min(other_d)
        closest = {"distance": d_min,
                   "repeats_beyond": float((rep > d_min).mean()) if rep.size else math.nan,
                   "copies_beyond": float((own > d_min).mean()) if own.size else math.nan}
    return {"tau": tau, "objects": len(by_obj), "with_copies": int(own.size),
            "taken_for_another": sorted(confused, key=lambda r: r[2]),
            "apart_from_copies": sorted(split, key=lambda r: -r[1]), "closest": closest}


def segmentation_stats(looks: list[Look]) -> dict[str, Any]:
    """ROI purity and merges over every look."""
    purities = np.asarray([lk.purity for lk in looks if lk.obj is not None])
    merges = [lk for lk in looks if len(lk.merged) > 1]
    return {
        "rois": len(looks),
        "rois_on_ground": sum(1 for lk in looks if lk.obj is None),
        "purity_median": float(np.median(purities)) if purities.size else math.nan,
        "purity_p05": float(np.percentile(purities, 5)) if purities.size else math.nan,
        "impure": int((purities < PURE_SHARE).sum()),
        "merges": len(merges),
        "merged_pairs": sorted({" + ".join(sorted(lk.merged)) for lk in merges}),
    }


def position_stats(looks: Iterable[Look], world: WorldSpec) -> dict[str, Any]:
    """Where ROIs are placed: x, y of every look at one object (uncut, pure, no merge)
    against its footprint centre (the world file's position), in metres, and how far one
    object's looks lie from their own mean (the jitter between looks; objects seen more
    than once). Objects partly hidden by another are included: this is what the spatial
    map receives."""
    centre = {o.name: np.asarray(o.position[:2], float) for o in world.objects}
    by_obj: dict[str, list[np.ndarray]] = defaultdict(list)
    for lk in looks:
        if (lk.obj is not None and lk.obj in centre and not lk.roi.cut
                and lk.purity >= PURE_SHARE and len(lk.merged) <= 1):
            by_obj[lk.obj].append(np.asarray(lk.roi.position[:2], float))
    errors = np.asarray([float(np.hypot(*(p - centre[o]))) for o, ps in by_obj.items()
                         for p in ps])
    jitter = np.asarray([float(np.hypot(*(p - np.mean(ps, axis=0)))) for ps in by_obj.values()
                         if len(ps) > 1 for p in ps])  # one look has no jitter to show
    if errors.size == 0:
        return {"looks": 0, "error_median": math.nan, "error_p95": math.nan,
                "error_max": math.nan, "over_3cm": 0, "jitter_median": math.nan,
                "jitter_p95": math.nan}
    if jitter.size == 0:
        jitter = np.full(1, math.nan)
    return {
        "looks": int(errors.size),
        "error_median": float(np.median(errors)),
        "error_p95": float(np.percentile(errors, 95)),
        "error_max": float(errors.max()),
        "over_3cm": int((errors > 0.03).sum()),
        "jitter_median": float(np.median(jitter)),
        "jitter_p95": float(np.percentile(jitter, 95)),
    }


def report(log: LookLog, memory_config: MemoryConfig | None = None) -> dict[str, Any]:
    """Everything ``roger features`` writes to features.json.

    Args:
        memory_config: The memory whose distance ``memory_separability`` measures (None:
            the calibration of the looks' mode).

    Raises:
        ValueError: The looks are not of the log's mode.
    """
    mode = log.feature_mode
    if log.looks and looks_mode(log.looks) is not mode:
        raise ValueError(f"looks of the {looks_mode(log.looks).value} mode in a log of the "
                         f"{mode.value} mode")
    names = feature_names(mode)
    looks = [lk for lk in log.looks if lk.stage != NOISE_STAGE]
    focus = [lk for lk in looks if lk.stage == "scan" or lk.focus]
    focus_stats = feature_stats(focus, log.world, names)
    return {
        "world": log.world.source, "frames": log.frames, "feature_mode": mode.value,
        "all_looks": feature_stats(looks, log.world, names),
        "focus_looks": focus_stats,
        "sensor_noise": noise_stats(log.looks, focus_stats["between"]),
        "memory_separability": memory_separability(
            looks, log.world, memory_config or MemoryConfig.for_mode(mode)),
        "segmentation": segmentation_stats(looks),
        "positions": position_stats(looks, log.world),
        "ratio_target": RATIO_TARGET,
    }


#: What each feature mode measures, for the report's first lines.
MODE_TEXT: dict[FeatureMode, str] = {
    FeatureMode.PAPER: "the eleven features of equations 1-5",
    FeatureMode.EXTENDED: "the paper's eleven, then " + " ".join(SHAPE_FEATURE_NAMES),
}


def _unknown(within: float) -> bool:
    """A feature no look measured: its within-object spread is NaN (``feature_stats``)."""
    return not math.isfinite(within)


def extended_summary(s: dict[str, Any]) -> str | None:
    """One line on the features beyond the paper's (``feature_stats`` output ``s``): their
    mean between/within ratio over the finite ones, and which are infinite or unknown;
    None when ``s`` has none."""
    new = [i for i, f in enumerate(s["features"]) if f in SHAPE_FEATURE_NAMES]
    if not new:
        return None
    ratio, within = s["ratio"], s["within"]
    finite = [i for i in new if math.isfinite(ratio[i])]
    inf = [i for i in new if math.isinf(ratio[i])]
    unknown = [i for i in new if _unknown(within[i])]
    # Measured, yet 0 / 0 (alike on every object) or NaN / x (a single category).
    no_ratio = [i for i in new if i not in finite + inf + unknown]
    old = [r for f, r in zip(s["features"], ratio, strict=True)
           if f in FEATURE_NAMES and math.isfinite(r)]

    def names(idx: list[int]) -> str:
        return ", ".join(s["features"][i] for i in idx)

    mean = f"{np.mean([ratio[i] for i in finite]):.2f} over {names(finite)}" if finite \
        else "- (none finite)"
    return ("**Extended features**: mean between/within ratio " + mean
            + (f"; infinite (no spread within one object): {names(inf)}" if inf else "")
            + (f"; unknown (never measured): {names(unknown)}" if unknown else "")
            + (f"; no ratio (no spread, or one category): {names(no_ratio)}"
               if no_ratio else "")
            + (f" (the paper's eleven: {np.mean(old):.2f} over their finite ratios)."
               if old else "."))


def markdown(result: dict[str, Any]) -> str:
    """The report as a Markdown table."""
    lines = [f"Features on `{result['world']}` ({result['frames']} frames)."]
    if "feature_mode" in result:
        mode = FeatureMode.parse(result["feature_mode"])
        lines.append(f"Feature mode: {mode.value} ({MODE_TEXT[mode]}).")
    lines.append("")
    for key, title in (("focus_looks", "initial-scan looks and looks at the focus"),
                       ("all_looks", "every look (all ROIs of every frame)")):
        s = result[key]
        lines += [f"**{title}**: {s['looks']} pure looks of {s['objects']} objects in "
                  f"{s['categories']} categories.", "",
                  "| feature | within-object sd | between-category sd | ratio | "
                  "between-copies sd | between-category / between-copies |",
                  "|---|---|---|---|---|---|"]
        for f, w, b, r, c, rc in zip(s["features"], s["within"], s["between"], s["ratio"],
                                     s["copies"], s["ratio_copies"], strict=True):
            if _unknown(w):
                lines.append(f"| {f} | unknown | - | - | - | - |")
                continue
            flag = "" if not math.isfinite(r) or r >= result["ratio_target"] else " (< 2)"
            lines.append(f"| {f} | {w:.4f} | {b:.4f} | {r:.2f}{flag} | {c:.4f} | {rc:.2f} |")
        lines += ["", f"Two looks of one object: median {s['look_distance_median']:.4f}, "
                  f"p90 {s['look_distance_p90']:.4f} (RMS over the features known in both); "
                  f"two copies of one category (their mean looks): median "
                  f"{s['copy_distance_median']:.4f}; "
                  f"the two nearest categories: {s['nearest_categories_distance']:.4f} apart.",
                  ""]
        summary = extended_summary(s) if key == "focus_looks" else None
        if summary:
            lines += [summary, ""]
    noise = result.get("sensor_noise")
    if noise and noise["visits"]:
        target = result["ratio_target"]
        lines += [f"**Sensor noise** (repeated looks at one fixation, {noise['visits']} "
                  "places): the spread of one fixation's looks, and the ceiling, the "
                  "between-category spread over it: what the ratio would be if one "
                  "object's looks differed by sensor noise alone.", "",
                  "| feature | same-fixation sd | ceiling |", "|---|---|---|"]
        for f, sd, c in zip(noise["features"], noise["sd"], noise["ceiling"], strict=True):
            if not math.isfinite(sd):  # no two looks of one fixation measured it
                lines.append(f"| {f} | unknown | - |")
                continue
            flag = "" if not math.isfinite(c) or c >= target else f" (< {target:g})"
            lines.append(f"| {f} | {sd:.4f} | {c:.2f}{flag} |")
        lines.append("")
    sep = result.get("memory_separability")
    if sep and sep["objects"]:
        took = ", ".join(f"{a} as {b} {d:.1f}" for a, b, d in sep["taken_for_another"][:6])
        apart = ", ".join(f"{a} {d:.1f}" for a, d in sep["apart_from_copies"][:6])
        more = ", ..."
        lines += [f"**The memory's distance** (looks at the focus with W known, "
                  f"showing one object, ground around it included; "
                  f"{sep['objects']} objects; the median of each look's distance to the "
                  f"nearest look of another object, in the memory's calibrated units, "
                  f"acceptance tau = {sep['tau']:.2f}): "
                  f"{len(sep['taken_for_another'])} objects lie within tau of another "
                  f"category"
                  + (f" ({took}{more if len(sep['taken_for_another']) > 6 else ''})"
                     if took else "")
                  + f"; {len(sep['apart_from_copies'])} of {sep['with_copies']} lie beyond "
                  f"it from their own category's other copies"
                  + (f" ({apart}{more if len(sep['apart_from_copies']) > 6 else ''})"
                     if apart else "") + "."]
        c = sep["closest"]
        if c and c["distance"] < sep["tau"]:
            lines += ["", f"The nearest other category lies {c['distance']:.2f} away: a "
                      f"threshold that parts it would call novel "
                      f"{100 * c['repeats_beyond']:.0f} % of the pairs of one object's "
                      f"looks and {100 * c['copies_beyond']:.0f} % of the objects seen "
                      f"again as copies."]
        lines.append("")
    g = result["segmentation"]
    lines += [f"**ROIs**: {g['rois']} ({g['rois_on_ground']} on no object); purity median "
              f"{g['purity_median']:.3f}, 5th percentile {g['purity_p05']:.3f}; "
              f"{g['impure']} below {PURE_SHARE}; {g['merges']} merge two objects"
              + (f" ({', '.join(g['merged_pairs'])})" if g["merged_pairs"] else "") + ".", ""]
    p = result.get("positions")
    if p and p["looks"]:
        lines += [f"**Positions** (x, y of {p['looks']} uncut, pure looks against the "
                  f"footprint centre): median {100 * p['error_median']:.1f} cm, 95th "
                  f"percentile {100 * p['error_p95']:.1f} cm, worst "
                  f"{100 * p['error_max']:.1f} cm, {p['over_3cm']} over 3 cm; one object's "
                  f"looks from their mean: median {100 * p['jitter_median']:.1f} cm, 95th "
                  f"percentile {100 * p['jitter_p95']:.1f} cm.", ""]
    return "\n".join(lines)


def plot(result: dict[str, Any], path: Path) -> None:
    """Within vs between spread per feature, focus looks, with the ratio target."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = result["focus_looks"]
    x = np.arange(len(s["features"]))
    # The paper's eleven fit 11 inches; the extended mode's bars get the same width.
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(max(11.0, len(x)), 4.2))
    ax.bar(x - 0.27, s["within"], 0.27, label="within one object (sd)", color="tab:red")
    ax.bar(x, np.nan_to_num(np.asarray(s["copies"], float)), 0.27,
           label="between copies of a category (sd)", color="tab:purple")
    ax.bar(x + 0.27, s["between"], 0.27, label="between categories (sd)", color="tab:blue")
    ax.set_xticks(x, s["features"])
    ax.set_ylabel("feature units")
    ax.legend(fontsize="small")
    ax.set_title("Spread of each feature")
    ratio = np.nan_to_num(np.asarray(s["ratio"], float), nan=0.0, posinf=np.inf)
    # An infinite ratio (W: no spread within an object once felt) is drawn as a bar just
    # above the others, marked, instead of one that scales the axis to 1e308.
    finite = ratio[np.isfinite(ratio)]
    top = 1.15 * max(float(finite.max()) if finite.size else 0.0, result["ratio_target"])
    shown = np.where(np.isfinite(ratio), ratio, top)
    bx.bar(x, shown, color=["tab:green" if r >= result["ratio_target"] else "tab:orange"
                            for r in ratio])
    for k in np.flatnonzero(~np.isfinite(ratio)):
        bx.text(x[k], top, "inf", ha="center", va="bottom")
    for j, w in enumerate(s["within"]):
        if _unknown(w):  # never measured: no bar, say so instead of a ratio of 0
            bx.text(x[j], 0.0, "?", ha="center", va="bottom")
    bx.set_ylim(0.0, 1.1 * top)
    noise = result.get("sensor_noise")
    if noise and noise["visits"]:
        ceiling = np.asarray(noise["ceiling"], float)
        ok = np.isfinite(ceiling)
        bx.plot(x[ok], np.minimum(ceiling[ok], top), "kv", ms=6,
                label="ceiling (sensor noise alone)")
    bx.axhline(result["ratio_target"], color="k", ls="--", lw=1, label="target")
    bx.set_xticks(x, s["features"])
    bx.set_ylabel("between / within")
    bx.set_title("Does each feature tell categories apart?")
    bx.legend()
    fig.suptitle(f"{Path(result['world']).name}: looks of the initial scan and of the focus")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def write_looks_csv(log: LookLog, path: Path) -> None:
    """Every look, one row: stage, gaze, focus, object, purity, position, features.

    The feature columns are those of the looks' mode (``feature_names``). An unknown
    feature is written as its value (0), so ``known`` (one 0/1 per feature, in that order)
    says which were measured: D of a cut or occluded silhouette, I/T/S of a ROI with too
    little rim of its own, W (and the touch features) before a haptic improvement. ``place``
    is the spatial-map place the gaze aimed at (-1 for the scan); the ``noise`` stage's
    rows are the repeated looks at one fixation (not in the spreads of features.md)."""
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["stage", "gaze", "focus", "object", "purity", "merged", "x", "y", "z",
                    *feature_names(log.feature_mode), "W_known", "known", "place"])
        for lk in log.looks:
            r = lk.roi
            w.writerow([lk.stage, lk.gaze, int(lk.focus), lk.obj or "", f"{lk.purity:.3f}",
                        "+".join(lk.merged), *(f"{v:.4f}" for v in r.position),
                        *(f"{v:.5f}" for v in r.features), int(r.known[WEIGHT_INDEX]),
                        "".join("1" if k else "0" for k in r.known), lk.place])


def write(log: LookLog, out: Path, memory_config: MemoryConfig | None = None
          ) -> dict[str, Any]:
    """features.json, features.md, features.png and looks.csv in ``out``.

    Args:
        memory_config: The memory whose distance the report measures (None: the
            calibration of the looks' mode).
    """
    out.mkdir(parents=True, exist_ok=True)
    result = report(log, memory_config)
    atomic_write_bytes(out / "features.json", (json.dumps(result, indent=2) + "\n").encode())
    atomic_write_bytes(out / "features.md", markdown(result).encode())
    write_looks_csv(log, out / "looks.csv")
    plot(result, out / "features.png")
    return result
