"""Objects of a world as pybullet bodies: shapes, grey surfaces and generated textures.

Each object's body frame sits at the centre of its bounding box, so it rests on the
ground at z = height / 2. Surface grey = intensity / 255; a textured object alternates
that grey with half of it (stripes: vertical bands, checker: squares).
"""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import cv2
import numpy as np
import pybullet as pb

from roger_common.types import ObjectSpec
from roger_sim.world import shape_height

#: Texture image size in pixels and the number of bands/squares across it.
TEXTURE_PIXELS: int = 64
TEXTURE_PERIODS: int = 4


def prism_mesh(size: float) -> tuple[list[list[float]], list[int], list[list[float]]]:
    """Vertices, triangle indices and uvs of a triangular prism.

    The triangle (side ``size``) stands in the body's y-z plane, facing +/-x, extruded
    ``size / 2`` along x; the body frame is at the centre of the bounding box.
    """
    h = shape_height("prism", size)
    d = size / 4.0
    tri = [(-size / 2.0, -h / 2.0), (size / 2.0, -h / 2.0), (0.0, h / 2.0)]
    verts: list[list[float]] = []
    uvs: list[list[float]] = []
    idx: list[int] = []

    def quad_or_tri(points: list[tuple[float, float, float]],
                    uv: list[tuple[float, float]]) -> None:
        base = len(verts)
        verts.extend([list(p) for p in points])
        uvs.extend([list(t) for t in uv])
        idx.extend([base, base + 1, base + 2])
        if len(points) == 4:
            idx.extend([base, base + 2, base + 3])

    # Front (-x) and back (+x) triangles, counter-clockwise seen from outside.
    quad_or_tri([(-d, tri[0][0], tri[0][1]), (-d, tri[2][0], tri[2][1]),
                 (-d, tri[1][0], tri[1][1])], [(0, 0), (0.5, 1), (1, 0)])
    quad_or_tri([(d, tri[0][0], tri[0][1]), (d, tri[1][0], tri[1][1]),
                 (d, tri[2][0], tri[2][1])], [(0, 0), (1, 0), (0.5, 1)])
    # The three rectangular sides.
    for a, b in ((0, 1), (1, 2), (2, 0)):
        pa, pb_ = tri[a], tri[b]
        quad_or_tri([(-d, pa[0], pa[1]), (-d, pb_[0], pb_[1]), (d, pb_[0], pb_[1]),
                     (d, pa[0], pa[1])], [(0, 0), (1, 0), (1, 1), (0, 1)])
    return verts, idx, uvs


def face_normals(verts: list[list[float]], idx: list[int]) -> list[list[float]]:
    """Outward normal of each vertex's face (every face has vertices of its own).

    TinyRenderer needs them: without normals a mesh is shaded and culled wrongly (seen: a
    prism 60 degrees to the side rendered as a sliver in one eye and not at all in the
    other).
    """
    v = np.asarray(verts, float)
    normals = np.zeros_like(v)
    for k in range(0, len(idx), 3):
        a, b, c = idx[k:k + 3]
        n = np.cross(v[b] - v[a], v[c] - v[a])
        normals[[a, b, c]] = n / np.linalg.norm(n)
    return normals.tolist()


def texture_image(texture: str, grey: float) -> np.ndarray:
    """Grey texture image (uint8, H x W x 3) alternating ``grey`` with ``grey / 2``."""
    n = TEXTURE_PIXELS
    cell = n // (2 * TEXTURE_PERIODS)
    u = np.arange(n) // cell
    if texture == "stripes":
        mask = np.broadcast_to(u[None, :] % 2 == 0, (n, n))
    elif texture == "checker":
        mask = (u[None, :] + u[:, None]) % 2 == 0
    else:
        mask = np.ones((n, n), bool)
    level = np.where(mask, grey, grey / 2.0)
    img = np.clip(np.round(level * 255.0), 0, 255).astype(np.uint8)
    return np.repeat(img[:, :, None], 3, axis=2)


class ObjectFactory:
    """Creates and removes object bodies in one pybullet client, caching textures."""

    def __init__(self, client: int) -> None:
        self.client = client
        self._textures: dict[tuple[str, float], int] = {}

    def _texture(self, texture: str, grey: float) -> int:
        key = (texture, round(grey, 6))
        if key not in self._textures:
            # pybullet loads textures from files only: write one into a private temporary
            # folder that is removed at once.
            with tempfile.TemporaryDirectory(prefix="roger_tex_") as tmp:
                path = Path(tmp) / "texture.png"
                cv2.imwrite(str(path), texture_image(texture, grey))
                self._textures[key] = pb.loadTexture(str(path), physicsClientId=self.client)
        return self._textures[key]

    def create(self, spec: ObjectSpec) -> int:
        """Create the body of ``spec`` resting on the ground; returns its unique id."""
        c = self.client
        grey = spec.intensity / 255.0
        colour = [grey, grey, grey, 1.0] if spec.texture == "plain" else [1.0, 1.0, 1.0, 1.0]
        s = spec.size
        if spec.shape == "box":
            col = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=[s / 2] * 3,
                                          physicsClientId=c)
            vis = pb.createVisualShape(pb.GEOM_BOX, halfExtents=[s / 2] * 3, rgbaColor=colour,
                                       physicsClientId=c)
        elif spec.shape == "sphere":
            col = pb.createCollisionShape(pb.GEOM_SPHERE, radius=s / 2, physicsClientId=c)
            vis = pb.createVisualShape(pb.GEOM_SPHERE, radius=s / 2, rgbaColor=colour,
                                       physicsClientId=c)
        elif spec.shape == "cylinder":
            col = pb.createCollisionShape(pb.GEOM_CYLINDER, radius=s / 2, height=s,
                                          physicsClientId=c)
            vis = pb.createVisualShape(pb.GEOM_CYLINDER, radius=s / 2, length=s,
                                       rgbaColor=colour, physicsClientId=c)
        elif spec.shape == "prism":
            verts, idx, uvs = prism_mesh(s)
            col = pb.createCollisionShape(pb.GEOM_MESH, vertices=verts, physicsClientId=c)
            vis = pb.createVisualShape(pb.GEOM_MESH, vertices=verts, indices=idx, uvs=uvs,
                                       normals=face_normals(verts, idx), rgbaColor=colour,
                                       physicsClientId=c)
        else:
            raise ValueError(f"unknown shape {spec.shape!r}")
        z = shape_height(spec.shape, s) / 2.0
        body = pb.createMultiBody(baseMass=spec.weight, baseCollisionShapeIndex=col,
                                  baseVisualShapeIndex=vis, basePosition=[*spec.position, z],
                                  baseOrientation=pb.getQuaternionFromEuler([0, 0, spec.yaw]),
                                  useMaximalCoordinates=True, physicsClientId=c)
        pb.changeDynamics(body, -1, lateralFriction=0.8, rollingFriction=0.01,
                          spinningFriction=0.01, physicsClientId=c)
        if spec.texture != "plain":
            pb.changeVisualShape(body, -1, textureUniqueId=self._texture(spec.texture, grey),
                                 rgbaColor=colour, physicsClientId=c)
        return body

    def move(self, body: int, spec: ObjectSpec) -> None:
        """Put ``body`` back on the ground at ``spec``'s position and yaw, at rest."""
        z = shape_height(spec.shape, spec.size) / 2.0
        pb.resetBasePositionAndOrientation(body, [*spec.position, z],
                                           pb.getQuaternionFromEuler([0, 0, spec.yaw]),
                                           physicsClientId=self.client)
        pb.resetBaseVelocity(body, [0, 0, 0], [0, 0, 0], physicsClientId=self.client)

    def remove(self, body: int) -> None:
        """Delete ``body`` from the simulation."""
        pb.removeBody(body, physicsClientId=self.client)


def yaw_of(quaternion: tuple[float, float, float, float]) -> float:
    """Rotation about z of an orientation quaternion (x, y, z, w), radians."""
    x, y, z, w = quaternion
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
