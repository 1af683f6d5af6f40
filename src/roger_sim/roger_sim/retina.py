"""Roger's retinas: one pinhole camera per eye, rendered by pybullet's TinyRenderer.

The TinyRenderer shades every pixel with the Phong model (ambient + diffuse + specular,
light from the world file's direction); the RGB result is converted to one intensity in
[0, 1]. Everything in Roger's world is grey, so intensity = mean of R, G, B / 255.
Pixels where the ray hits nothing (sky, beyond the far plane) get the ground's grey so
the horizon does not make an edge. Pixel noise is added by the simulator, not here.
"""

from __future__ import annotations

import time

import numpy as np
import pybullet as pb

from roger_common.types import CameraModel, EyePose
from roger_sim.config import SimConfig


class Retina:
    """Renders intensity and object-id images for a camera pose.

    Args:
        client: pybullet physics client id.
        config: Image size, field of view, clipping planes and Phong coefficients.
        light_direction: Where the light comes from (pybullet's ``lightDirection``).
    """

    def __init__(self, client: int, config: SimConfig,
                 light_direction: tuple[float, float, float]) -> None:
        self.client = client
        self.config = config
        self.light_direction = [float(c) for c in light_direction]
        n = config.image_size
        self.camera = CameraModel(width=n, height=n, focal_px=config.focal_px)
        projection = list(pb.computeProjectionMatrixFOV(
            fov=config.fov_deg, aspect=1.0, nearVal=config.near_clip, farVal=config.far_clip,
            physicsClientId=client))
        # The TinyRenderer samples pixels at integer positions, half a pixel off the
        # pinhole model whose pixel centres sit at +0.5 (roger_common.geometry). Shift the
        # principal point by half a pixel (column 2 of the column-major matrix) so that a
        # point projecting to (u, v) is drawn there.
        projection[8] += 1.0 / n
        projection[9] += 1.0 / n
        self._projection = projection
        #: Wall seconds spent inside pybullet's renderer by this retina (the floor).
        self.seconds = 0.0

    def render(self, pose: EyePose) -> tuple[np.ndarray, np.ndarray]:
        """Render one retina.

        Args:
            pose: Camera pose in the robot frame, OpenCV axes (right, down, forward).

        Returns:
            (intensity, body_ids): float32 (H, W) intensity in [0, 1] without noise, and
            int32 (H, W) pybullet body unique ids (-1 where nothing was hit).
        """
        n = self.config.image_size
        forward = pose.rotation[:, 2]
        up = -pose.rotation[:, 1]
        eye = pose.position
        view = pb.computeViewMatrix(cameraEyePosition=eye.tolist(),
                                    cameraTargetPosition=(eye + forward).tolist(),
                                    cameraUpVector=up.tolist(), physicsClientId=self.client)
        cfg = self.config
        t0 = time.perf_counter()
        _, _, rgba, _, seg = pb.getCameraImage(
            n, n, viewMatrix=view, projectionMatrix=self._projection,
            lightDirection=self.light_direction, lightColor=[1.0, 1.0, 1.0],
            lightDistance=cfg.light_distance, shadow=int(cfg.shadows),
            lightAmbientCoeff=cfg.light_ambient, lightDiffuseCoeff=cfg.light_diffuse,
            lightSpecularCoeff=cfg.light_specular, renderer=pb.ER_TINY_RENDERER,
            physicsClientId=self.client)
        self.seconds += time.perf_counter() - t0
        rgb = np.asarray(rgba, np.uint8).reshape(n, n, 4)[:, :, :3]
        intensity = rgb.astype(np.float32).sum(axis=2) / np.float32(3.0 * 255.0)
        ids = np.asarray(seg, np.int32).reshape(n, n)
        # Segmentation values carry the link index in the high bits only with a flag we
        # do not pass, so they are body ids; -1 is "nothing", i.e. the sky.
        intensity[ids < 0] = np.float32(cfg.ground_grey)
        return intensity, ids

