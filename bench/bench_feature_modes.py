"""Cost of the extended features: ``Perception.process`` in the paper and the extended mode
on the same stereo frames, alternated in one process (ratios, not absolute times: shared
machines are noisy).

Run: ``.venv/bin/python bench/bench_feature_modes.py [--world worlds/inspection.yaml]
[--frames 40] [--rounds 5]``. The frames are the robot's own looks (an attention shift, a
visual and a haptic improvement at each object, simulator seed 0).
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

from roger_common.types import Action, Goal, StereoFrame
from roger_perception.config import PerceptionConfig
from roger_perception.perception import Perception
from roger_sim.config import SimConfig
from roger_sim.simulator import Simulator
from roger_sim.world import load_world


def frames(world: Path, n: int) -> list[StereoFrame]:
    """Up to ``n`` frames: shift, visual and haptic improvement at each object in turn."""
    spec = load_world(world)
    out: list[StereoFrame] = []
    with Simulator(spec, SimConfig(), seed=0) as sim:
        poses = sim.object_poses()
        goal = 0
        for name in poses:
            x, y, z, _ = poses[name]
            for action in (Action.ATTENTION_SHIFT, Action.VISUAL_IMPROVEMENT,
                           Action.HAPTIC_IMPROVEMENT):
                goal += 1
                out.append(sim.run_goal(Goal(goal, action, (x, y, z)))[1])
                if len(out) >= n:
                    return out
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--world", type=Path, default=Path("worlds/inspection.yaml"))
    p.add_argument("--frames", type=int, default=40)
    p.add_argument("--rounds", type=int, default=5)
    args = p.parse_args()
    looks = frames(args.world, args.frames)
    seconds: dict[str, list[float]] = {"paper": [], "extended": []}
    for _ in range(args.rounds):
        for mode in ("paper", "extended"):
            perception = Perception(PerceptionConfig(features=mode))
            t0 = time.perf_counter()
            for frame in looks:
                perception.process(frame)
            seconds[mode].append((time.perf_counter() - t0) / len(looks))
    paper, extended = (statistics.median(seconds[m]) for m in ("paper", "extended"))
    print(f"{len(looks)} frames of {args.world}, {args.rounds} rounds alternated: "
          f"paper {paper * 1e3:.2f} ms/frame, extended {extended * 1e3:.2f} ms/frame, "
          f"extended / paper {extended / paper:.3f} (median of rounds)")


if __name__ == "__main__":
    main()
