"""How far behind a fixated object another one stands, as the two foveae would see it.

Diagnosis for the in-line occlusion that fails most fresh closed-loop runs (docs/perception.md,
"Limits": an object standing in line behind a nearer one joins its ROI, so it is never
visited, and the nearer one's top outline, grey and size are read off both). The robot
renders the left eye's fovea only; this bench also renders the right eye's, with the same
camera, after the same visual improvement (both eyes verge on the fixated object, so its
disparity is about 0 there), adds the retina's pixel noise for the improvement's exposures,
and matches 7 x 7 windows along the rows (1 px steps, +-24 px; a sketch of what a fovea
stereo step in perception could do, not a method of perception). For every object with
pixels in the left fovea it prints the median disparity of its textured pixels (horizontal
gradient over 0.02), labels only to group them::

    python bench/fovea_stereo.py --world WORLD.yaml --fixate c02_2

Not a test, not a result on its own: the worlds it is run on are looked at.
"""

from __future__ import annotations

import argparse
import math

import cv2
import numpy as np

from roger_common.types import Action, Goal, WorldSpec
from roger_sim.config import SimConfig
from roger_sim.simulator import Simulator
from roger_sim.world import load_world

#: Half-width of the matched windows, fovea pixels.
HALF: int = 3
#: Disparities searched on either side of the fixation's, fovea pixels.
RANGE: int = 24
#: A pixel takes part where the smoothed fovea's horizontal gradient exceeds this.
GRADIENT: float = 0.02


def row_disparity(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """Per left pixel, the horizontal shift d in [-RANGE, RANGE] that best matches its
    window in the right image at u + d (sum of absolute differences)."""
    h, w = left.shape
    ls, rs = (cv2.GaussianBlur(im.astype(np.float32), (0, 0), 0.7) for im in (left, right))
    costs = np.empty((2 * RANGE + 1, h, w), np.float32)
    for k, d in enumerate(range(-RANGE, RANGE + 1)):
        shifted = cv2.warpAffine(rs, np.array([[1, 0, d], [0, 1, 0]], np.float32), (w, h),
                                 flags=cv2.INTER_LINEAR, borderValue=-1.0)
        cost = np.abs(ls - shifted)
        cost[shifted < 0] = 0.2
        costs[k] = cv2.boxFilter(cost, -1, (2 * HALF + 1, 2 * HALF + 1))
    return (np.argmin(costs, axis=0) - RANGE).astype(np.float32)


def main() -> None:
    """Command line: one line per object the left fovea shows."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--world", required=True, help="world file (YAML)")
    p.add_argument("--fixate", required=True, help="name of the object to fixate")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args()
    world = load_world(args.world)
    cfg = SimConfig()
    rng = np.random.default_rng(args.seed)
    with Simulator(world, cfg, seed=args.seed) as sim:
        x, y, z, _ = sim.object_poses()[args.fixate]
        sim.run_goal(Goal(1, Action.ATTENTION_SHIFT, (x, y, z)))
        _, frame = sim.run_goal(Goal(2, Action.VISUAL_IMPROVEMENT, (x, y, z)))
        if frame.fovea is None or sim.fovea_retina is None:
            raise SystemExit("no fovea: SimConfig.fovea_fov_deg is 0")
        right, _ = sim.fovea_retina.render(sim.robot.eye_pose("right"))
        _, ids = sim.fovea_retina.render(sim.robot.eye_pose("left"))
        bodies = sim.object_bodies()
    sigma = cfg.pixel_noise / math.sqrt(cfg.improve_exposures)
    right = np.clip(right + rng.normal(0.0, sigma, right.shape), 0.0, 1.0)
    disparity = row_disparity(np.asarray(frame.fovea), right)
    smooth = cv2.GaussianBlur(np.asarray(frame.fovea, np.float32), (0, 0), 0.7)
    textured = np.abs(cv2.Sobel(smooth, cv2.CV_32F, 1, 0, ksize=3)) > GRADIENT
    print(f"{args.world}: fixating {args.fixate} at ({x:.3f}, {y:.3f})")
    for name, body in bodies.items():
        mine = ids == body
        if not mine.any():
            continue
        m = mine & textured
        distance = math.hypot(*sim_xy(world, name))
        if not m.any():
            print(f"  {name:10s} {int(mine.sum()):5d} px, {distance:.2f} m: no textured pixel")
            continue
        q1, med, q3 = np.quantile(disparity[m], [0.25, 0.5, 0.75])
        print(f"  {name:10s} {int(mine.sum()):5d} px, {distance:.2f} m: disparity median "
              f"{med:+.1f} px (quartiles {q1:+.1f} .. {q3:+.1f}, {int(m.sum())} textured px)")


def sim_xy(world: WorldSpec, name: str) -> tuple[float, float]:
    """The object's position in the world file (metres, robot frame)."""
    spec = next(o for o in world.objects if o.name == name)
    return float(spec.position[0]), float(spec.position[1])


if __name__ == "__main__":
    main()
