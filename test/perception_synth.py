"""A small synthetic stereo renderer for the perception tests (not a test module).

It ray-casts simple shapes (cubes, spheres, upright cylinders) resting on a dark ground
into two verging pinhole eyes built with roger_common.geometry.look_rotation, like the
simulator: grey = intensity / 255 with Lambert shading (ambient + diffuse), 2x2
supersampling at the edges, optional seeded pixel noise whose std falls with
sqrt(exposures), as a visual improvement does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from roger_common.geometry import look_rotation
from roger_common.types import CameraModel, EyePose, HapticReading, StereoFrame

GROUND_LEVEL = 0.02
AMBIENT = 0.6
DIFFUSE = 0.4
LIGHT = np.array([1.0, 0.5, 1.0]) / np.linalg.norm([1.0, 0.5, 1.0])


@dataclass(frozen=True)
class Shape:
    """One object on the ground.

    Attributes:
        shape: "cube", "sphere" or "cylinder".
        x, y: Ground position of its centre, robot frame, metres.
        size: Side, diameter, or diameter = height, metres.
        intensity: 0..255; grey = intensity / 255.
        yaw: Rotation about z (cubes only), radians.
    """

    shape: str
    x: float
    y: float
    size: float
    intensity: float
    yaw: float = 0.0

    @property
    def centre(self) -> tuple[float, float, float]:
        """Centre of the object's volume."""
        return (self.x, self.y, self.size / 2.0)


def camera_model(width: int = 128, fov_deg: float = 60.0) -> CameraModel:
    """Square retina with the given horizontal field of view."""
    focal = (width / 2.0) / math.tan(math.radians(fov_deg) / 2.0)
    return CameraModel(width=width, height=width, focal_px=focal)


def eye_poses(gaze: tuple[float, float, float], baseline: float = 0.16,
              eye_height: float = 0.45) -> tuple[EyePose, EyePose]:
    """Left (+y) and right eyes both fixating ``gaze``."""
    poses = []
    for side in (1.0, -1.0):
        pos = np.array([0.0, side * baseline / 2.0, eye_height])
        poses.append(EyePose(position=pos, rotation=look_rotation(pos, np.asarray(gaze))))
    return poses[0], poses[1]


def _hit(shape: Shape, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ray parameter t (inf on a miss) and unit normals for rays o + t d, d (N, 3)."""
    n = d.shape[0]
    t = np.full(n, np.inf)
    normal = np.zeros((n, 3))
    r = shape.size / 2.0
    c = np.array(shape.centre)
    if shape.shape == "sphere":
        oc = o - c
        b = d @ oc
        disc = b * b - (oc @ oc - r * r)
        ok = disc >= 0
        tt = -b[ok] - np.sqrt(disc[ok])
        t[ok] = np.where(tt > 0, tt, np.inf)
        p = o + t[:, None] * d
        normal = (p - c) / r
    elif shape.shape == "cube":
        cy, sy = math.cos(shape.yaw), math.sin(shape.yaw)
        rot = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
        ol = rot.T @ (o - c)
        dl = d @ rot
        with np.errstate(divide="ignore", invalid="ignore"):
            t1 = (-r - ol) / dl
            t2 = (r - ol) / dl
        tmin = np.minimum(t1, t2)
        tmax = np.maximum(t1, t2)
        tnear = np.nanmax(tmin, axis=1)
        tfar = np.nanmin(tmax, axis=1)
        ok = (tnear <= tfar) & (tnear > 0)
        t[ok] = tnear[ok]
        axis = np.nanargmax(tmin, axis=1)
        nl = np.zeros((n, 3))
        nl[np.arange(n), axis] = -np.sign(dl[np.arange(n), axis])
        normal = nl @ rot.T
    elif shape.shape == "cylinder":
        oc = o - c
        a = d[:, 0] ** 2 + d[:, 1] ** 2
        b = d[:, 0] * oc[0] + d[:, 1] * oc[1]
        cc = oc[0] ** 2 + oc[1] ** 2 - r * r
        disc = b * b - a * cc
        ok = (disc >= 0) & (a > 1e-12)
        ts = np.full(n, np.inf)
        ts[ok] = (-b[ok] - np.sqrt(disc[ok])) / a[ok]
        zs = o[2] + ts * d[:, 2]
        side = np.isfinite(ts) & (ts > 0) & (zs >= 0) & (zs <= shape.size)
        with np.errstate(divide="ignore", invalid="ignore"):
            tc = (shape.size - o[2]) / d[:, 2]
        pc = o + tc[:, None] * d
        cap = (tc > 0) & ((pc[:, 0] - c[0]) ** 2 + (pc[:, 1] - c[1]) ** 2 <= r * r)
        t = np.where(side, ts, np.inf)
        use_cap = cap & (tc < t)
        t = np.where(use_cap, tc, t)
        p = o + np.where(np.isfinite(t), t, 0.0)[:, None] * d
        normal = np.zeros((n, 3))
        normal[:, 0] = (p[:, 0] - c[0]) / r
        normal[:, 1] = (p[:, 1] - c[1]) / r
        normal[use_cap] = (0.0, 0.0, 1.0)
    else:
        raise ValueError(f"unknown shape {shape.shape!r}")
    return t, normal


def render(objects: list[Shape], camera: CameraModel, pose: EyePose, supersample: int = 2
           ) -> tuple[np.ndarray, np.ndarray]:
    """Noise-free retina image (float32, [0, 1]) and labels (-1 ground, i object i)."""
    w, h, ss = camera.width, camera.height, supersample
    sub = (np.arange(w * ss) + 0.5) / ss
    uu, vv = np.meshgrid(sub, (np.arange(h * ss) + 0.5) / ss)
    d_cam = np.stack([(uu - w / 2.0) / camera.focal_px, (vv - h / 2.0) / camera.focal_px,
                      np.ones_like(uu)], axis=-1).reshape(-1, 3)
    d = d_cam @ pose.rotation.T
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = np.asarray(pose.position, float)
    best = np.full(d.shape[0], np.inf)
    value = np.full(d.shape[0], GROUND_LEVEL)
    label = np.full(d.shape[0], -1)
    for i, obj in enumerate(objects):
        # Only rays that meet the object's bounding sphere need the exact test.
        oc = o - np.array(obj.centre)
        b = d @ oc
        near = np.flatnonzero(b * b - (oc @ oc - (0.9 * obj.size) ** 2) >= 0)
        t, normal = _hit(obj, o, d[near])
        closer = t < best[near]
        idx = near[closer]
        best[idx] = t[closer]
        shade = AMBIENT + DIFFUSE * np.clip(normal[closer] @ LIGHT, 0.0, 1.0)
        value[idx] = obj.intensity / 255.0 * shade
        label[idx] = i
    img = value.reshape(h, ss, w, ss).mean(axis=(1, 3))
    lab = label.reshape(h * ss, w * ss)[ss // 2::ss, ss // 2::ss]
    return img.astype(np.float32), lab.astype(np.int32)


@lru_cache(maxsize=64)
def _clean_pair(objects: tuple[Shape, ...], gaze: tuple[float, float, float], width: int,
                baseline: float, eye_height: float):
    camera = camera_model(width)
    left_pose, right_pose = eye_poses(gaze, baseline, eye_height)
    left = render(list(objects), camera, left_pose)
    right = render(list(objects), camera, right_pose)
    return camera, left_pose, right_pose, left, right


def make_frame(objects: list[Shape], gaze: tuple[float, float, float] = (0.9, 0.0, 0.05),
               width: int = 128, noise_std: float = 0.01, exposures: int = 1, seed: int = 0,
               haptic: HapticReading | None = None, baseline: float = 0.16,
               eye_height: float = 0.45, stamp: float = 0.0) -> StereoFrame:
    """A StereoFrame of ``objects`` with both eyes fixating ``gaze``.

    Pixel noise: N(0, noise_std / sqrt(exposures)) from a generator seeded with ``seed``,
    then clipped to [0, 1]. Noise-free renders are cached, so repeated noisy frames of
    one scene are cheap.
    """
    camera, left_pose, right_pose, left, right = _clean_pair(
        tuple(objects), tuple(float(g) for g in gaze), int(width), float(baseline),
        float(eye_height))
    rng = np.random.default_rng(seed)
    images = []
    for img, _ in (left, right):
        if noise_std > 0:
            img = img + rng.normal(0.0, noise_std / math.sqrt(exposures), img.shape)
        images.append(np.clip(img, 0.0, 1.0).astype(np.float32))
    return StereoFrame(
        stamp=stamp, goal_id=0, left=images[0], right=images[1], camera=camera,
        left_pose=left_pose, right_pose=right_pose, exposures=exposures, haptic=haptic,
        left_labels=left[1].copy(), right_labels=right[1].copy(),
        label_names=tuple(f"obj{i}" for i in range(len(objects))),
    )


#: Four objects like those of Table 1: same shape and size, intensity 99/79/69/59 and
#: weights 15/10/10/5 divided by 10 (kg), to fit the 2 kg an arm can lift.
TABLE1 = ((99.0, 1.5), (79.0, 1.0), (69.0, 1.0), (59.0, 0.5))
#: Ground positions that keep four 0.1 m objects apart in both retinas.
SPREAD = ((0.85, 0.27), (0.85, 0.09), (0.85, -0.09), (0.85, -0.27))
#: A gaze point in the middle of SPREAD.
CENTRE_GAZE = (0.88, 0.0, 0.05)


def table1_objects(shape: str = "cube", size: float = 0.1,
                   positions: tuple[tuple[float, float], ...] = SPREAD) -> list[Shape]:
    """The four Table-1-like objects at ``positions`` (object i at positions[i])."""
    return [Shape(shape, x, y, size, inten)
            for (inten, _), (x, y) in zip(TABLE1, positions, strict=True)]


def nearest_object(position: tuple[float, float, float], objects: list[Shape]) -> int:
    """Index of the object whose centre is nearest ``position``."""
    d = [np.linalg.norm(np.asarray(position) - np.asarray(o.centre)) for o in objects]
    return int(np.argmin(d))
