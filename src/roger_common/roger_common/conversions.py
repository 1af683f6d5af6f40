"""Messages <-> the plain types of roger_common.types: every conversion of a shared type.

The types the packages exchange (goals, stereo frames, haptic readings, ROIs, memory
requests and results) are roger_common's, so their conversions live here, next to them:
sim, perception, memory and attention convert through this module and never import one
another. Conversions of a package's own types stay in that package's ``conversions.py``.
Node plumbing (QoS, parameters, ``spin_node``) is in ``ros_node``.
"""

from __future__ import annotations

import math
from collections import Counter

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, Pose, Quaternion, Vector3
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import Header

from roger_common import frames
from roger_common.errors import MessageError
from roger_common.geometry import eye_pose, quaternion_from_rotation
from roger_common.types import (
    Action,
    CameraModel,
    EyePose,
    FeatureMode,
    Goal,
    HapticReading,
    MatchOutcome,
    MatchResult,
    MemoryOp,
    MemoryRequest,
    Roi,
    StereoFrame,
    TactileContact,
    feature_dim,
    mode_of_dim,
)
from roger_interfaces.msg import ActionGoal, MemoryResult, RoiArray, StereoGeometry
from roger_interfaces.msg import HapticReading as HapticReadingMsg
from roger_interfaces.msg import MemoryRequest as MemoryRequestMsg
from roger_interfaces.msg import Roi as RoiMsg

# Images, camera infos and ground-truth labels name the eyes' optical frames (REP 103);
# positions (ROIs, goals, the spatial map) are in the base frame (roger_common.frames).
LEFT_FRAME = frames.LEFT_OPTICAL_FRAME
RIGHT_FRAME = frames.RIGHT_OPTICAL_FRAME
ROBOT_FRAME = frames.BASE_FRAME

# What a message from outside the graph may carry (docs/reliability.md, "Bad input"): a
# msg_to_* conversion raises MessageError beyond these bounds, and the node drops it.
#: Image sides, pixels: the simulator renders at most 1024 (SimConfig.image_size), and
#: perception copes with any size down to one pixel (it finds no ROI there).
IMAGE_SIDE_RANGE: tuple[int, int] = (1, 1024)
#: Largest |coordinate| of a goal's target, metres: far beyond any depth a 1024 px retina
#: can measure (about 140 m at one pixel of disparity), so no goal of the graph's own is
#: refused; beyond it a target is nonsense that would only upset the controllers.
TARGET_LIMIT_M: float = 1000.0
#: Most ROIs one array may hold (perception finds a few dozen at most).
MAX_ROIS: int = 1024
#: Largest deviation of an eye pose's quaternion norm from 1.
QUATERNION_TOLERANCE: float = 1e-3
#: The fovea is the left eye's: same pose and optical axis, a narrower field.
FOVEA_FRAME = LEFT_FRAME
#: The right fovea is the right eye's.
FOVEA_RIGHT_FRAME = RIGHT_FRAME


def seconds_to_time(t: float) -> Time:
    """Simulated seconds as a builtin_interfaces/Time."""
    sec = int(math.floor(t))
    return Time(sec=sec, nanosec=int(round((t - sec) * 1e9)) % 1_000_000_000)


def time_to_seconds(t: Time) -> float:
    """A builtin_interfaces/Time as seconds."""
    return t.sec + t.nanosec * 1e-9


def point(p: tuple[float, float, float] | np.ndarray) -> Point:
    """A geometry_msgs/Point from three numbers."""
    return Point(x=float(p[0]), y=float(p[1]), z=float(p[2]))


def point_tuple(p: Point) -> tuple[float, float, float]:
    """A geometry_msgs/Point as a tuple."""
    return (p.x, p.y, p.z)


def rotation_to_quaternion(r: np.ndarray) -> Quaternion:
    """A 3x3 rotation matrix as a unit quaternion (Shepperd's method)."""
    x, y, z, w = quaternion_from_rotation(r)
    return Quaternion(x=x, y=y, z=z, w=w)




def pose_msg(position: np.ndarray, rotation: np.ndarray) -> Pose:
    """A geometry_msgs/Pose from a position and a rotation matrix."""
    return Pose(position=point(position), orientation=rotation_to_quaternion(rotation))


def eye_pose_msg(pose: EyePose) -> Pose:
    """An eye pose as a Pose; its own quaternion when it has one (exact round trip)."""
    if pose.quaternion is None:
        return pose_msg(pose.position, pose.rotation)
    x, y, z, w = pose.quaternion
    return Pose(position=point(pose.position), orientation=Quaternion(x=x, y=y, z=z, w=w))


def msg_to_eye_pose(p: Pose) -> EyePose:
    """A Pose as an EyePose (rotation rebuilt from the quaternion, which it keeps)."""
    o = p.orientation
    return eye_pose(point_tuple(p.position), (o.x, o.y, o.z, o.w))


def header(stamp: float, frame_id: str = ROBOT_FRAME) -> Header:
    """A std_msgs/Header at simulated time ``stamp``."""
    return Header(stamp=seconds_to_time(stamp), frame_id=frame_id)


# -- goals -------------------------------------------------------------------------------
def goal_to_msg(goal: Goal, stamp: float, map_revision: int = 0) -> ActionGoal:
    """A core Goal as an ActionGoal; ``map_revision``: the spatial map to perceive it with."""
    return ActionGoal(header=header(stamp), goal_id=goal.goal_id, action=int(goal.action),
                      target=point(goal.target), arm=goal.arm, map_revision=int(map_revision))


def msg_to_goal(msg: ActionGoal) -> Goal:
    """An ActionGoal as a core Goal.

    Raises:
        MessageError: An unknown action or a map update, a target that is not finite or
            farther than ``TARGET_LIMIT_M`` on an axis, an arm other than -1, 0 or 1.
    """
    try:
        action = Action(msg.action)
    except ValueError:
        raise MessageError(f"goal {msg.goal_id}: unknown action {msg.action} "
                           "(0 attention shift, 1 visual, 2 haptic improvement)") from None
    if action == Action.MAP_UPDATE:
        raise MessageError(f"goal {msg.goal_id}: a map update is not a physical goal")
    target = point_tuple(msg.target)
    if not all(math.isfinite(v) and abs(v) <= TARGET_LIMIT_M for v in target):
        raise MessageError(f"goal {msg.goal_id}: target {target} is not finite or beyond "
                           f"{TARGET_LIMIT_M:g} m")
    if msg.arm not in (-1, 0, 1):
        raise MessageError(f"goal {msg.goal_id}: arm {msg.arm} (-1 either, 0 left, 1 right)")
    return Goal(goal_id=int(msg.goal_id), action=action, target=target, arm=int(msg.arm))


# -- retinas and their geometry ----------------------------------------------------------
def image_msg(img: np.ndarray, stamp: float, frame_id: str) -> Image:
    """A float32 retina image in [0, 1] as a 32FC1 sensor_msgs/Image."""
    data = np.ascontiguousarray(img, dtype=np.float32)
    h, w = data.shape
    return Image(header=header(stamp, frame_id), height=h, width=w, encoding="32FC1",
                 is_bigendian=0, step=4 * w, data=data.tobytes())


def image_to_array(msg: Image) -> np.ndarray:
    """A retina image (32FC1 in [0, 1], or mono8) as float32 (H, W).

    Raises:
        MessageError: Another encoding, a side outside ``IMAGE_SIDE_RANGE``, a step or data
            length that does not fit the size, values that are not finite or outside [0, 1].
    """
    lo, hi = IMAGE_SIDE_RANGE
    if not (lo <= msg.width <= hi and lo <= msg.height <= hi):
        raise MessageError(f"image {msg.width}x{msg.height}: each side must be in "
                           f"[{lo}, {hi}] px")
    if msg.encoding == "32FC1":
        if msg.step != 4 * msg.width or len(msg.data) != msg.step * msg.height:
            raise MessageError(f"32FC1 image {msg.width}x{msg.height}: step {msg.step} and "
                               f"{len(msg.data)} bytes do not fit")
        img = np.frombuffer(bytes(msg.data), dtype="<f4" if not msg.is_bigendian else ">f4")
        img = img.reshape(msg.height, msg.width).astype(np.float32)
    elif msg.encoding == "mono8":
        if len(msg.data) != msg.step * msg.height or msg.step < msg.width:
            raise MessageError(f"mono8 image {msg.width}x{msg.height}: wrong data size")
        rows = np.frombuffer(bytes(msg.data), np.uint8).reshape(msg.height, msg.step)
        img = rows[:, : msg.width].astype(np.float32) / 255.0
    else:
        raise MessageError(f"image encoding {msg.encoding!r} not supported (use 32FC1 or mono8)")
    if not np.all(np.isfinite(img)):
        raise MessageError("image holds NaN or infinite values")
    if img.min() < 0.0 or img.max() > 1.0:
        raise MessageError(f"image values in [{img.min():g}, {img.max():g}], not [0, 1]")
    return img


def camera_info_msg(camera: CameraModel, stamp: float, frame_id: str,
                    baseline: float, right: bool) -> CameraInfo:
    """CameraInfo of one retina; the right one carries -f*baseline in P like a stereo rig."""
    f = camera.focal_px
    cx, cy = camera.width / 2.0, camera.height / 2.0
    tx = -f * baseline if right else 0.0
    return CameraInfo(
        header=header(stamp, frame_id), height=camera.height, width=camera.width,
        distortion_model="plumb_bob", d=[0.0] * 5,
        k=[f, 0.0, cx, 0.0, f, cy, 0.0, 0.0, 1.0],
        r=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        p=[f, 0.0, cx, tx, 0.0, f, cy, 0.0, 0.0, 0.0, 1.0, 0.0])


def camera_from_info(msg: CameraInfo) -> CameraModel:
    """The pinhole model of a CameraInfo (fx from K). Raises MessageError when unusable."""
    focal = float(msg.k[0])
    lo, hi = IMAGE_SIDE_RANGE
    if (not (lo <= msg.width <= hi and lo <= msg.height <= hi) or not math.isfinite(focal)
            or focal <= 0 or focal > 1e6):
        raise MessageError(f"camera info {msg.width}x{msg.height} with focal length {focal} "
                           f"is unusable (need sides in [{lo}, {hi}] px and a focal length "
                           "in (0, 1e6] px)")
    return CameraModel(width=int(msg.width), height=int(msg.height), focal_px=focal)


def stereo_geometry_msg(frame: StereoFrame, map_revision: int = 0) -> StereoGeometry:
    """The eye poses of a stereo pair; ``map_revision`` comes from the goal that made it."""
    return StereoGeometry(
        header=header(frame.stamp), goal_id=frame.goal_id,
        left_eye=eye_pose_msg(frame.left_pose), right_eye=eye_pose_msg(frame.right_pose),
        exposures=frame.exposures, map_revision=int(map_revision),
        haptic=frame.haptic is not None, fovea=frame.fovea is not None,
        fovea_right=frame.fovea is not None and frame.fovea_right is not None)


def poses_from_geometry(msg: StereoGeometry) -> tuple[EyePose, EyePose]:
    """Left and right eye poses of a StereoGeometry message. Raises MessageError on NaN."""
    def one(p: Pose) -> EyePose:
        o = p.orientation
        norm = math.sqrt(o.x * o.x + o.y * o.y + o.z * o.z + o.w * o.w)
        if not abs(norm - 1.0) <= QUATERNION_TOLERANCE:  # NaN included
            raise MessageError(f"stereo geometry of goal {msg.goal_id}: eye orientation is "
                               f"not a unit quaternion (norm {norm:g})")
        pose = msg_to_eye_pose(p)
        if not (np.all(np.isfinite(pose.position)) and np.all(np.isfinite(pose.rotation))):
            raise MessageError(f"stereo geometry of goal {msg.goal_id}: eye pose not finite")
        return pose
    return one(msg.left_eye), one(msg.right_eye)


# -- touch -------------------------------------------------------------------------------
def haptic_msg(reading: HapticReading, goal_id: int, stamp: float) -> HapticReadingMsg:
    """A core HapticReading as a message (its tactile contacts as three parallel arrays)."""
    contacts = reading.contacts
    return HapticReadingMsg(header=header(stamp), goal_id=goal_id, arm=reading.arm,
                            contact=reading.contact, position=point(reading.position),
                            weight=float(reading.weight),
                            contact_points=[point(c.point) for c in contacts],
                            contact_normals=[Vector3(x=float(c.normal[0]), y=float(c.normal[1]),
                                                     z=float(c.normal[2])) for c in contacts],
                            probe_offsets=[float(v) for c in contacts for v in c.probe],
                            **_tactile_images(contacts))


def _tactile_images(contacts: tuple[TactileContact, ...]) -> dict[str, object]:
    """The contacts' tactile images as the message's three fields (none when any contact
    has no image: a reading's touches come from one array)."""
    if not contacts or any(not c.image for c in contacts):
        return {"tactile_taxels": 0, "tactile_pitch": 0.0, "tactile_images": []}
    return {"tactile_taxels": contacts[0].taxels, "tactile_pitch": float(contacts[0].pitch),
            "tactile_images": [float(v) for c in contacts for v in c.image]}


def msg_to_haptic(msg: HapticReadingMsg) -> HapticReading:
    """A haptic message as a core reading.

    A reading without contact (the hand closed on nothing) carries NaN weight and is kept
    as it is. Raises MessageError on a contact with a NaN or negative weight or position,
    and on malformed tactile contacts: array lengths that do not match, values that are
    not finite, normals that are not unit vectors, contacts on a reading without contact.
    """
    what = f"haptic reading of goal {msg.goal_id}"
    points = [point_tuple(p) for p in msg.contact_points]
    normals = [(n.x, n.y, n.z) for n in msg.contact_normals]
    offsets = [float(v) for v in msg.probe_offsets]
    if len(normals) != len(points) or len(offsets) != 2 * len(points):
        raise MessageError(f"{what}: {len(points)} contact points, {len(normals)} normals and "
                           f"{len(offsets)} probe offsets (expected 2 per contact)")
    if not all(math.isfinite(v) for v in [*(c for p in points + normals for c in p), *offsets]):
        raise MessageError(f"{what}: tactile contacts not finite")
    if any(abs(math.hypot(*n) - 1.0) > 1e-3 for n in normals):
        raise MessageError(f"{what}: a contact normal is not a unit vector")
    if not msg.contact:
        if points:
            raise MessageError(f"{what}: {len(points)} tactile contacts but contact is false")
        return HapticReading(arm=int(msg.arm), contact=False,
                             position=point_tuple(msg.position), weight=float(msg.weight))
    if not math.isfinite(msg.weight) or msg.weight < 0:
        raise MessageError(f"{what}: weight {msg.weight} unusable")
    if not all(math.isfinite(v) for v in point_tuple(msg.position)):
        raise MessageError(f"{what}: position not finite")
    n = int(msg.tactile_taxels)
    images = [float(v) for v in msg.tactile_images]
    if len(images) != n * n * len(points) or (n and not math.isfinite(msg.tactile_pitch)):
        raise MessageError(f"{what}: {len(images)} tactile image values for {len(points)} "
                           f"contacts of {n} x {n} taxels")
    size = n * n
    contacts = tuple(TactileContact(point=p, normal=n_, probe=(offsets[2 * i], offsets[2 * i + 1]),
                                    image=tuple(images[i * size:(i + 1) * size]),
                                    pitch=float(msg.tactile_pitch) if n else 0.0)
                     for i, (p, n_) in enumerate(zip(points, normals, strict=True)))
    return HapticReading(arm=int(msg.arm), contact=True, position=point_tuple(msg.position),
                         weight=float(msg.weight), contacts=contacts)


# -- regions of interest -----------------------------------------------------------------
def roi_to_msg(roi: Roi) -> RoiMsg:
    """A core Roi as a message."""
    x0, y0, x1, y1 = roi.bbox
    return RoiMsg(id=int(roi.roi_id), x0=int(x0), y0=int(y0), x1=int(x1), y1=int(y1),
                  position=point(roi.position),
                  features=[float(v) for v in roi.features], known=[bool(k) for k in roi.known],
                  activation=float(roi.activation), retinal_size=float(roi.retinal_size),
                  mean_intensity=float(roi.mean_intensity), motion=float(roi.motion),
                  tactile=float(roi.tactile), mapped=bool(roi.mapped), cut=bool(roi.cut),
                  size_m=float(roi.size_m))


def msg_to_roi(msg: RoiMsg, mode: FeatureMode | str = FeatureMode.PAPER) -> Roi:
    """A Roi message as a core Roi. Raises MessageError on a malformed one.

    Args:
        msg: The message.
        mode: The feature mode of its array (``RoiArray.feature_mode``).
    """
    features = np.asarray(msg.features, dtype=np.float32)
    known = np.asarray(msg.known, dtype=bool)
    n = feature_dim(mode)
    if features.shape != (n,) or known.shape != (n,):
        raise MessageError(f"ROI {msg.id}: {features.size} features and {known.size} known "
                           f"flags, expected {n} each ({FeatureMode.parse(mode).value} mode)")
    if not np.all(np.isfinite(features)) or features.min() < -1e-6 or features.max() > 1 + 1e-6:
        raise MessageError(f"ROI {msg.id}: features outside [0, 1] or NaN")
    pos = point_tuple(msg.position)
    if not all(math.isfinite(v) for v in pos):
        raise MessageError(f"ROI {msg.id}: position {pos} is not finite")
    scalars = {"activation": msg.activation, "retinal_size": msg.retinal_size,
               "mean_intensity": msg.mean_intensity, "motion": msg.motion,
               "tactile": msg.tactile, "size_m": msg.size_m}
    bad = [name for name, v in scalars.items() if not math.isfinite(v)]
    if bad:
        raise MessageError(f"ROI {msg.id}: {', '.join(bad)} not finite")
    return Roi(roi_id=int(msg.id), bbox=(msg.x0, msg.y0, msg.x1, msg.y1), position=pos,
               features=features, known=known, activation=float(msg.activation),
               retinal_size=float(msg.retinal_size), mean_intensity=float(msg.mean_intensity),
               motion=float(msg.motion), tactile=float(msg.tactile), mapped=bool(msg.mapped),
               cut=bool(msg.cut), size_m=float(msg.size_m))


def rois_to_msg(rois: list[Roi], stamp: float, goal_id: int,
                mode: FeatureMode | str = FeatureMode.PAPER) -> RoiArray:
    """All ROIs of one stereo pair, whose feature vectors are of ``mode``."""
    return RoiArray(header=header(stamp), goal_id=int(goal_id),
                    feature_mode=FeatureMode.parse(mode).value,
                    rois=[roi_to_msg(r) for r in rois])


def roi_array_mode(msg: RoiArray) -> FeatureMode:
    """The feature mode a RoiArray says it carries (empty: the paper's, as before the
    modes). Raises MessageError for an unknown name."""
    return _mode(msg.feature_mode, f"ROI array of goal {msg.goal_id}")


def msg_to_rois(msg: RoiArray) -> list[Roi]:
    """A RoiArray as core Rois (raises MessageError on the first malformed ROI)."""
    if len(msg.rois) > MAX_ROIS:
        raise MessageError(f"ROI array of goal {msg.goal_id}: {len(msg.rois)} ROIs, at most "
                           f"{MAX_ROIS}")
    ids = [int(r.id) for r in msg.rois]
    if len(set(ids)) != len(ids):
        repeated = sorted(i for i, n in Counter(ids).items() if n > 1)[:8]
        raise MessageError(f"ROI array of goal {msg.goal_id}: ROI ids repeat ({repeated})")
    mode = roi_array_mode(msg)
    return [msg_to_roi(r, mode) for r in msg.rois]


def _mode(name: str, what: str) -> FeatureMode:
    try:
        return FeatureMode.parse(name or FeatureMode.PAPER.value)
    except ValueError as exc:
        raise MessageError(f"{what}: {exc}") from None


# -- the associative memory --------------------------------------------------------------
def msg_to_request(msg: MemoryRequestMsg) -> MemoryRequest:
    """A request message as a core MemoryRequest. Raises MessageError when unusable."""
    try:
        op = MemoryOp(msg.op)
    except ValueError:
        raise MessageError(f"request {msg.request_id}: unknown op {msg.op} (0 match, 1 store)")
    features = np.asarray(msg.features, dtype=np.float32)
    known = np.asarray(msg.known, dtype=bool)
    mode = _mode(msg.feature_mode, f"request {msg.request_id}")
    n = feature_dim(mode)
    if features.shape != (n,) or known.shape != (n,):
        raise MessageError(f"request {msg.request_id}: {features.size} features and "
                           f"{known.size} known flags, expected {n} each ({mode.value} mode)")
    if not np.all(np.isfinite(features[known])):
        raise MessageError(f"request {msg.request_id}: NaN or infinite features")
    if features[known].size and (features[known].min() < -1e-6
                                 or features[known].max() > 1 + 1e-6):
        raise MessageError(f"request {msg.request_id}: features outside [0, 1]")
    return MemoryRequest(request_id=int(msg.request_id), op=op,
                         features=np.clip(np.nan_to_num(features), 0.0, 1.0), known=known,
                         final_trial=bool(msg.final_trial), focus_id=int(msg.focus_id))


def request_to_msg(req: MemoryRequest, stamp: float) -> MemoryRequestMsg:
    """A core MemoryRequest as a message."""
    return MemoryRequestMsg(header=Header(stamp=seconds_to_time(stamp)),
                            request_id=int(req.request_id), op=int(req.op),
                            feature_mode=mode_of_dim(len(req.features)).value,
                            features=[float(v) for v in req.features],
                            known=[bool(k) for k in req.known], final_trial=req.final_trial,
                            focus_id=int(req.focus_id))


def result_to_msg(request_id: int, op: MemoryOp, result: MatchResult, memory_size: int,
                  stamp: float) -> MemoryResult:
    """A core MatchResult as the reply to request ``request_id``."""
    return MemoryResult(header=Header(stamp=seconds_to_time(stamp)), request_id=int(request_id),
                        op=int(op), outcome=int(result.outcome), address=int(result.address),
                        confidence=float(result.confidence), memory_size=int(memory_size))


def msg_to_result(msg: MemoryResult) -> MatchResult:
    """A reply message as a core MatchResult.

    Raises:
        MessageError: An unknown op or outcome, a confidence that is not finite.
    """
    try:
        MemoryOp(msg.op)
        outcome = MatchOutcome(msg.outcome)
    except ValueError:
        raise MessageError(f"memory result {msg.request_id}: unknown op {msg.op} or outcome "
                           f"{msg.outcome}") from None
    if not math.isfinite(msg.confidence):
        raise MessageError(f"memory result {msg.request_id}: confidence {msg.confidence}")
    return MatchResult(outcome=outcome, address=int(msg.address),
                       confidence=float(msg.confidence))
