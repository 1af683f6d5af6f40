"""Cost of the extended features: ``Perception.process`` in the paper and the extended mode
on the same stereo frames, alternated in one process (ratios, not absolute times: shared
machines are noisy).

Run: ``.venv/bin/python bench/bench_feature_modes.py [--world worlds/inspection.yaml]
[--frames 40] [--rounds 5]``. The frames are the robot's own looks (an attention shift, a
visual and a haptic improvement at each object, simulator seed 0). It also renders the same
goals with and without the fovea of a visual improvement (``SimConfig.fovea_fov_deg``) and
reports the renderer's wall seconds per frame and per visual improvement (the fovea is
rendered only after one).
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


def frames(world: Path, n: int, config: SimConfig | None = None,
           render_seconds: list[float] | None = None) -> list[StereoFrame]:
    """Up to ``n`` frames: shift, visual and haptic improvement at each object in turn
    (``render_seconds``: gets the renderer's wall seconds of those frames appended)."""
    spec = load_world(world)
    out: list[StereoFrame] = []
    with Simulator(spec, config or SimConfig(), seed=0) as sim:
        try:
            _collect(sim, out, n)
        finally:
            if render_seconds is not None:
                render_seconds.append(sim.floor_seconds["render"])
    return out


def _collect(sim: Simulator, out: list[StereoFrame], n: int) -> None:
    poses = sim.object_poses()
    goal = 0
    for name in poses:
        x, y, z, _ = poses[name]
        for action in (Action.ATTENTION_SHIFT, Action.VISUAL_IMPROVEMENT,
                       Action.HAPTIC_IMPROVEMENT):
            goal += 1
            out.append(sim.run_goal(Goal(goal, action, (x, y, z)))[1])
            if len(out) >= n:
                return


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
    render: dict[float, list[float]] = {30.0: [], 0.0: []}
    for _ in range(args.rounds):
        for fov in render:
            frames(args.world, args.frames, SimConfig(fovea_fov_deg=fov), render[fov])
    with_f, without = (statistics.median(render[f]) for f in (30.0, 0.0))
    improvements = sum(1 for f in looks if f.fovea is not None)
    print(f"renderer: {with_f / len(looks) * 1e3:.2f} ms/frame with the fovea, "
          f"{without / len(looks) * 1e3:.2f} without, ratio {with_f / without:.3f}; "
          f"{(with_f - without) / max(improvements, 1) * 1e3:.2f} ms per fovea "
          f"({improvements} visual improvements of {len(looks)} frames)")


if __name__ == "__main__":
    main()
