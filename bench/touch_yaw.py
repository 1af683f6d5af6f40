"""How an object's touch features change with its yaw: the simulator's own touches only.

Not a test (a measurement for docs/perception.md, "TK along the chord"). For each shape and
size, one object of grey 81 stands alone at (0.55, 0) at each of twelve yaws (0-2.75 rad;
spheres and cylinders at three); the hand makes ``--readings`` haptic improvements 1.5 cm
apart on it, and ``touch_shape`` pools them as ``HapticMemory`` does. Prints per shape the
range over yaws of the pooled TH, TK and TC, and the 90th percentile and maximum of TK of
single readings::

    .venv/bin/python bench/touch_yaw.py
"""

from __future__ import annotations

import argparse
from collections import defaultdict

import numpy as np

from roger_common.types import Action, Goal, TactileContact
from roger_perception.shape import touch_shape
from roger_sim.config import SimConfig
from roger_sim.simulator import Simulator
from roger_sim.world import parse_world

SHAPES = (("prism", 0.10), ("prism", 0.14), ("box", 0.10), ("box", 0.14),
          ("cylinder", 0.12), ("sphere", 0.12))
YAWS = tuple(0.25 * k for k in range(12))


def readings(shape: str, size: float, yaw: float, n: int
             ) -> list[tuple[TactileContact, ...]]:
    """The contacts of ``n`` haptic improvements on one object (module docstring)."""
    world = parse_world({"name": "touch_yaw", "objects": [
        {"name": "o", "shape": shape, "position": [0.55, 0.0], "yaw": yaw, "size": size,
         "intensity": 81, "weight": 0.6}]}, "touch_yaw")
    out = []
    with Simulator(world, SimConfig(), seed=int(yaw * 100)) as sim:
        for k in range(n):
            x, y, z, _ = sim.object_poses()["o"]
            dx = (k - (n - 1) / 2.0) * 0.015
            sim.execute(Goal(k + 1, Action.HAPTIC_IMPROVEMENT, (x + dx, y + dx / 2, z)))
            reading = sim.last_haptic
            out.append(reading.contacts if reading is not None else ())
    return out


def main() -> None:
    """Command line (module docstring)."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--readings", type=int, default=5)
    args = p.parse_args()
    pooled: dict[tuple[str, float], list[tuple[float, float, float]]] = defaultdict(list)
    single: dict[tuple[str, float], list[float]] = defaultdict(list)
    for shape, size in SHAPES:
        yaws = YAWS if shape in ("prism", "box") else YAWS[:3]
        for yaw in yaws:
            rs = readings(shape, size, yaw, args.readings)
            value = touch_shape(rs)
            if value is not None:
                pooled[(shape, size)].append(value)
            for r in rs:
                one = touch_shape([r])
                if one is not None:
                    single[(shape, size)].append(one[1])
    print("shape size | pooled over yaws: TH TK TC (min-max) | single readings' TK: "
          "90th percentile, max")
    for key, values in pooled.items():
        v = np.asarray(values)
        ranges = " ".join(f"{lo:.2f}-{hi:.2f}" for lo, hi in zip(v.min(0), v.max(0)))
        s = np.asarray(single[key])
        print(f"{key[0]} {key[1]:.2f} | {ranges} | {np.quantile(s, 0.9):.2f}, {s.max():.2f}")


if __name__ == "__main__":
    main()
