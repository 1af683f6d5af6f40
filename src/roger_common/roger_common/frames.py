"""Names of Roger's coordinate frames (the TF tree and the URDF's links), REP 103 / REP 105.

``GROUND_FRAME`` is the fixed frame a viewer draws in (the world; the spatial map lives in
it). Roger stands still, so ``BASE_FRAME`` (the robot frame of every core module: origin on
the ground under the body, x forward, y left, z up) coincides with it through a static
identity transform. Below the base: the neck (pan), the head (tilt), each eye's camera
frame (x along the optical axis, y left, z up) and its optical frame (z along the optical
axis, x right, y down: what images and camera infos name), and each arm's links down to the
hand and its fingertip.
"""

from __future__ import annotations

#: World-fixed frame on the ground (REP 105's fixed frame for a robot that never moves).
GROUND_FRAME = "world"
#: Roger's base (the URDF's root link): the core modules' robot frame.
BASE_FRAME = "roger_base"
#: After the neck's pan joint.
NECK_FRAME = "roger_neck"
#: After the neck's tilt joint: the head that carries both eyes.
HEAD_FRAME = "roger_head"


def eye_frame(side: str) -> str:
    """Camera frame of the ``side`` ("left"/"right") eye, REP 103 body axes (x forward)."""
    return f"roger_{side}_eye"


def optical_frame(side: str) -> str:
    """Optical frame of the ``side`` eye: z forward, x right, y down (images name it)."""
    return f"roger_{side}_eye_optical"


def arm_link_frame(arm: str, part: str) -> str:
    """Frame of an arm's ``part`` ("shoulder", "upper_arm", "forearm", "hand",
    "fingertip"); ``arm`` is "left_arm" or "right_arm"."""
    return f"roger_{arm.removesuffix('_arm')}_{part}"


def hand_frame(arm: str) -> str:
    """Frame of the hand (the wrist, where the finger hangs from) of ``arm``."""
    return arm_link_frame(arm, "hand")


LEFT_EYE_FRAME = eye_frame("left")
RIGHT_EYE_FRAME = eye_frame("right")
LEFT_OPTICAL_FRAME = optical_frame("left")
RIGHT_OPTICAL_FRAME = optical_frame("right")
