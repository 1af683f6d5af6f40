"""Configuration of the simulator: one frozen, validated dataclass.

Values flow one way: ROS parameters -> ``SimConfig`` -> core. Every field is checked in
``__post_init__``; a bad value raises :class:`roger_common.errors.ConfigError` naming the
field and the value.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

from roger_common.errors import ConfigError


def _check(name: str, value: object, ok: bool, rule: str) -> None:
    if not ok:
        raise ConfigError(f"SimConfig.{name} = {value!r}: must be {rule}")


@dataclass(frozen=True)
class SimConfig:
    """Parameters of the Roger-the-Crab simulator.

    Attributes:
        image_size: Width and height of each retina in pixels (the original used 128).
        fov_deg: Field of view of each retina, degrees (vertical = horizontal, square).
        time_step: Physics step, simulated seconds.
        pixel_noise: Std of the Gaussian intensity noise added to each pixel, [0, 1] units.
        weight_noise_kg: Std of the Gaussian noise of a haptic weight measurement, kg.
        goal_timeout_s: Simulated seconds a goal may take before transient controllers fail.
        improve_exposures: Renders integrated after a visual improvement (noise / sqrt(n)).
        fovea_fov_deg: Field of view of the left eye's fovea, degrees: after a visual
            improvement the centre of the left eye's field is also rendered at
            ``fovea_size`` pixels (with ``improve_exposures``' noise), as primate and iCub
            eyes have a fovea. 0: no fovea. The extended features' O is measured on it.
        fovea_size: Width and height of the foveal image in pixels.
        fovea_stereo: Render the right eye's fovea too, with the left one (its own pixel
            noise): perception parts an object standing in line behind the fixated one by
            the two foveae's disparity (``roger_perception.fovea_layers``). False: the left
            fovea alone, as before.
        realtime: Sleep so that simulated time follows wall-clock time (for watching).
        gui: Open pybullet's own window instead of the headless DIRECT client.
        light_ambient: Phong ambient coefficient of the TinyRenderer.
        light_diffuse: Phong diffuse coefficient.
        light_specular: Phong specular coefficient.
        light_distance: Distance of the light from the world origin, metres.
        shadows: Let the TinyRenderer cast shadows.
        ground_grey: Grey level of the ground plane, [0, 1] (near black).
        robot_grey: Grey level of the robot's own links, [0, 1] (near black).
        near_clip: Near clipping distance of the retinas, metres.
        far_clip: Far clipping distance of the retinas, metres.
        head_bandwidth: Natural frequency of the neck and eye servos, rad/s.
        arm_bandwidth: Natural frequency of the arm servos, rad/s.
        shift_tolerance_rad: Joint error under which neck and eyes count as converged
            after an attention shift, radians.
        fine_tolerance_rad: Tighter eye tolerance of a visual improvement, radians.
        arm_tolerance: Joint error under which an arm phase counts as converged
            (radians for the planar joints, metres for the lift joint).
        velocity_tolerance: Joint speed under which a servo counts as at rest (rad/s, m/s).
        settle_steps: Consecutive steps within tolerance needed to converge.
        lift_height_m: How high a haptic improvement lifts an object, metres.
        touch_speed: Speed of the hand coming down onto an object, m/s.
        weigh_steps: Physics steps averaged for one weight measurement.
        probe_directions: Probe touches around the first touch of a haptic improvement
            (shape from touch), evenly spread directions from +x; 0: none.
        probe_radius_m: Horizontal distance of a probe touch from the first touch, metres.
        probe_step_m: Each probe touch whose tactile image was pressed all over (the pad
            lay on a top wider than itself, no rim under it) sends the later probes this
            much farther out, towards the rim of a wide top, metres; 0: every probe at
            ``probe_radius_m``.
        probe_rise_m: How far above the first touch the hand rises after a probe touch
            (it goes across once it is clear of the top, while still rising), metres.
        probe_depth_m: How far below the first touch a probe comes down before it counts
            as fallen off the object, metres.
        reach_slack_m: A haptic improvement whose target lies beyond the arm's reach by at
            most this much reaches as far as it can towards it instead (the target pulled
            back towards the shoulder to the edge of reach): an object at the edge of reach
            whose position the eyes put a centimetre or two too far still reaches into it
            (the smallest objects 4 cm from their centre), metres; 0: a target beyond
            reach fails at once.
        tactile_noise_m: Std of the Gaussian noise of a tactile contact point, metres.
        tactile_normal_noise_rad: Std of the Gaussian noise added to each component of a
            tactile contact's unit normal before it is normalised again (about that many
            radians of tilt per axis).
        tactile_taxels: Taxels along each side of the hand's square tactile array (the
            finger's 4 cm flat tip); each touch reports their image (``tactile_range_m``);
            0: no array, touches report a point and a normal only.
        tactile_range_m: Depth of the array's compliant skin: a taxel reports the surface's
            depth below the pad where it lies at most this far below it (pressed), and
            nothing where it lies deeper, metres.
        tactile_depth_noise_m: Std of the Gaussian noise of each taxel's depth, metres.
    """

    image_size: int = 128
    fov_deg: float = 60.0
    time_step: float = 1.0 / 240.0
    pixel_noise: float = 0.01
    weight_noise_kg: float = 0.02
    goal_timeout_s: float = 5.0
    improve_exposures: int = 4
    fovea_fov_deg: float = 30.0
    fovea_size: int = 192
    fovea_stereo: bool = True
    realtime: bool = field(default=False, metadata={"live": True})
    gui: bool = False
    light_ambient: float = 0.6
    light_diffuse: float = 0.35
    light_specular: float = 0.05
    light_distance: float = 10.0
    shadows: bool = False
    ground_grey: float = 0.05
    robot_grey: float = 0.05
    near_clip: float = 0.03
    far_clip: float = 60.0
    head_bandwidth: float = 40.0
    arm_bandwidth: float = 30.0
    shift_tolerance_rad: float = 0.005
    fine_tolerance_rad: float = 0.001
    arm_tolerance: float = 0.01
    velocity_tolerance: float = 0.05
    settle_steps: int = 3
    lift_height_m: float = 0.08
    touch_speed: float = 0.5
    weigh_steps: int = 24
    probe_directions: int = 3
    probe_radius_m: float = 0.04
    probe_step_m: float = 0.025
    probe_rise_m: float = 0.03
    probe_depth_m: float = 0.08
    reach_slack_m: float = 0.03
    tactile_noise_m: float = 0.001
    tactile_normal_noise_rad: float = 0.03
    tactile_taxels: int = 21
    tactile_range_m: float = 0.003
    tactile_depth_noise_m: float = 0.0001

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if f.type in ("bool", bool):
                _check(f.name, value, isinstance(value, bool), "true or false")
            elif f.type in ("int", int):
                _check(f.name, value, isinstance(value, int) and not isinstance(value, bool),
                       "an integer")
            else:
                _check(f.name, value, isinstance(value, (int, float))
                       and not isinstance(value, bool) and math.isfinite(value),
                       "a finite number")
        _check("image_size", self.image_size, 16 <= self.image_size <= 1024, "in [16, 1024]")
        _check("fov_deg", self.fov_deg, 10.0 <= self.fov_deg <= 120.0, "in [10, 120] degrees")
        _check("time_step", self.time_step, 1e-4 <= self.time_step <= 0.02,
               "in [1e-4, 0.02] s")
        _check("pixel_noise", self.pixel_noise, 0.0 <= self.pixel_noise <= 0.5, "in [0, 0.5]")
        _check("weight_noise_kg", self.weight_noise_kg, 0.0 <= self.weight_noise_kg <= 1.0,
               "in [0, 1] kg")
        _check("goal_timeout_s", self.goal_timeout_s, 0.1 <= self.goal_timeout_s <= 60.0,
               "in [0.1, 60] s")
        _check("improve_exposures", self.improve_exposures, 1 <= self.improve_exposures <= 64,
               "in [1, 64]")
        _check("fovea_fov_deg", self.fovea_fov_deg,
               self.fovea_fov_deg == 0.0 or 5.0 <= self.fovea_fov_deg < self.fov_deg,
               "0 (no fovea) or in [5, fov_deg) degrees")
        _check("fovea_size", self.fovea_size, 16 <= self.fovea_size <= 1024, "in [16, 1024]")
        for name in ("light_ambient", "light_diffuse", "light_specular", "ground_grey",
                     "robot_grey"):
            value = getattr(self, name)
            _check(name, value, 0.0 <= value <= 1.0, "in [0, 1]")
        _check("light_distance", self.light_distance, self.light_distance > 0, "> 0")
        _check("near_clip", self.near_clip, 0.001 <= self.near_clip < 0.1, "in [0.001, 0.1) m")
        _check("far_clip", self.far_clip, self.far_clip > 1.0, "> 1 m")
        for name in ("head_bandwidth", "arm_bandwidth"):
            value = getattr(self, name)
            # Explicit PD on a discrete step is stable only well below the Nyquist rate.
            limit = 0.5 / self.time_step
            _check(name, value, 1.0 <= value <= limit, f"in [1, {limit:g}] rad/s")
        for name in ("shift_tolerance_rad", "fine_tolerance_rad", "arm_tolerance",
                     "velocity_tolerance", "lift_height_m", "touch_speed"):
            value = getattr(self, name)
            _check(name, value, value > 0, "> 0")
        _check("fine_tolerance_rad", self.fine_tolerance_rad,
               self.fine_tolerance_rad <= self.shift_tolerance_rad,
               "<= shift_tolerance_rad")
        _check("lift_height_m", self.lift_height_m, self.lift_height_m <= 0.3, "<= 0.3 m")
        _check("settle_steps", self.settle_steps, 1 <= self.settle_steps <= 100, "in [1, 100]")
        _check("weigh_steps", self.weigh_steps, 1 <= self.weigh_steps <= 1000, "in [1, 1000]")
        _check("probe_directions", self.probe_directions, 0 <= self.probe_directions <= 16,
               "in [0, 16]")
        _check("probe_radius_m", self.probe_radius_m, 0.0 < self.probe_radius_m <= 0.2,
               "in (0, 0.2] m")
        _check("probe_step_m", self.probe_step_m, 0.0 <= self.probe_step_m <= 0.1,
               "in [0, 0.1] m")
        _check("probe_rise_m", self.probe_rise_m, 0.0 < self.probe_rise_m <= 0.2,
               "in (0, 0.2] m")
        _check("probe_depth_m", self.probe_depth_m, 0.0 < self.probe_depth_m <= 0.5,
               "in (0, 0.5] m")
        _check("reach_slack_m", self.reach_slack_m, 0.0 <= self.reach_slack_m <= 0.1,
               "in [0, 0.1] m")
        _check("tactile_noise_m", self.tactile_noise_m, 0.0 <= self.tactile_noise_m <= 0.05,
               "in [0, 0.05] m")
        _check("tactile_normal_noise_rad", self.tactile_normal_noise_rad,
               0.0 <= self.tactile_normal_noise_rad <= 0.5, "in [0, 0.5] rad")
        _check("tactile_taxels", self.tactile_taxels,
               self.tactile_taxels == 0 or 3 <= self.tactile_taxels <= 64, "0 or in [3, 64]")
        _check("tactile_range_m", self.tactile_range_m, 0.0 < self.tactile_range_m <= 0.02,
               "in (0, 0.02] m")
        _check("tactile_depth_noise_m", self.tactile_depth_noise_m,
               0.0 <= self.tactile_depth_noise_m <= 0.005, "in [0, 0.005] m")

    @property
    def focal_px(self) -> float:
        """Focal length in pixels of the square pinhole retina."""
        return (self.image_size / 2.0) / math.tan(math.radians(self.fov_deg) / 2.0)


@dataclass(frozen=True)
class SimNodeConfig:
    """What the simulator node needs besides SimConfig.

    Attributes:
        world: World file (YAML, docs/world-files.md).
        seed: Seed of pixel and sensor noise; same seed and world -> same images.
    """

    world: str = "worlds/table1.yaml"
    seed: int = 0

    def __post_init__(self) -> None:
        _check("world", self.world, isinstance(self.world, str) and bool(self.world),
               "a world file name")
        _check("seed", self.seed, isinstance(self.seed, int) and not isinstance(self.seed, bool)
               and self.seed >= 0, "an integer >= 0")
