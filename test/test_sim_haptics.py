"""Haptic improvement: reach, touch, lift and weigh Table 1's objects from joint torques."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from roger_common.types import Action, ControllerState, Goal
from roger_sim.config import SimConfig
from roger_sim.haptics import GRAVITY, weight_from_efforts
from roger_sim.simulator import Simulator
from roger_sim.world import load_world

TABLE1 = Path(__file__).resolve().parents[1] / "worlds" / "table1.yaml"
NOISE = 0.02


def test_weight_from_efforts() -> None:
    arm = np.full(10, 24.5)
    assert weight_from_efforts(arm + 1.5 * GRAVITY, arm) == pytest.approx(1.5)
    assert weight_from_efforts(arm, arm) == 0.0


@pytest.fixture(scope="module")
def table1_readings() -> dict[str, tuple]:
    world = load_world(TABLE1)
    out = {}
    with Simulator(world, SimConfig(weight_noise_kg=NOISE), seed=11) as sim:
        start = sim.object_poses()
        for i, obj in enumerate(world.objects, start=1):
            x, y, z, _ = start[obj.name]
            report, frame = sim.run_goal(Goal(i, Action.HAPTIC_IMPROVEMENT, (x, y, z)))
            out[obj.name] = (report, sim.last_haptic, frame, sim.object_poses()[obj.name],
                             start[obj.name])
    return out


def test_table1_weights_keep_order_and_ratios(table1_readings: dict) -> None:
    w = {name: r[1].weight for name, r in table1_readings.items()}
    assert w["obj01"] > w["obj02"] > w["obj04"] and w["obj01"] > w["obj03"] > w["obj04"]
    # 15 / 10 / 10 / 5 within the sensor noise (4 sigma) plus 2 % of model error.
    for name, true in (("obj01", 1.5), ("obj02", 1.0), ("obj03", 1.0), ("obj04", 0.5)):
        assert abs(w[name] - true) < 4 * NOISE + 0.02 * true, (name, w[name])
    assert w["obj01"] / w["obj04"] == pytest.approx(3.0, rel=0.25)
    assert w["obj02"] / w["obj03"] == pytest.approx(1.0, rel=0.12)


def test_haptic_reports_and_returns(table1_readings: dict) -> None:
    for name, (report, reading, frame, after, before) in table1_readings.items():
        assert report.converged, (name, report.states)
        arm = "left_arm" if before[1] >= 0 else "right_arm"
        assert report.states[arm] == ControllerState.CONVERGED
        assert reading.arm == (0 if arm == "left_arm" else 1)
        assert reading.contact
        assert reading.position[2] == pytest.approx(0.3, abs=0.01)  # the top of the box
        assert math.dist(reading.position[:2], before[:2]) < 0.05
        assert frame.haptic == reading
        # The object is put back where it stood, upright.
        assert math.dist(after[:2], before[:2]) < 0.02 and abs(after[2] - before[2]) < 0.005
        assert report.physics_steps * 1 / 240 < 3.0


def test_touching_nothing_and_choosing_the_arm() -> None:
    world = load_world(TABLE1)
    with Simulator(world, SimConfig(weight_noise_kg=0.0)) as sim:
        report = sim.execute(Goal(1, Action.HAPTIC_IMPROVEMENT, (0.5, 0.0, 0.05), arm=1))
        reading = sim.last_haptic
        assert reading is not None and reading.arm == 1 and not reading.contact
        assert math.isnan(reading.weight)
        assert report.states["right_arm"] == ControllerState.CONVERGED
        # A non-haptic goal clears last_haptic.
        sim.execute(Goal(2, Action.ATTENTION_SHIFT, (0.8, 0.2, 0.1)))
        assert sim.last_haptic is None and sim.render().haptic is None
