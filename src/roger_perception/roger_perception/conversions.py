"""Messages <-> roger_perception core types. Every message conversion of the package is here."""

from __future__ import annotations

import math

import numpy as np
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import Header

from roger_common.conversions import msg_to_eye_pose, point, point_tuple, seconds_to_time
from roger_common.errors import MessageError
from roger_common.types import FEATURE_DIM, CameraModel, EyePose, HapticReading, Roi
from roger_interfaces.msg import HapticReading as HapticReadingMsg
from roger_interfaces.msg import Roi as RoiMsg
from roger_interfaces.msg import RoiArray, SpatialMap, StereoGeometry


def image_to_array(msg: Image) -> np.ndarray:
    """A retina image (32FC1 in [0, 1], or mono8) as float32 (H, W). Raises MessageError."""
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
    return img


def camera_from_info(msg: CameraInfo) -> CameraModel:
    """The pinhole model of a CameraInfo (fx from K). Raises MessageError when unusable."""
    focal = float(msg.k[0])
    if msg.width <= 0 or msg.height <= 0 or not math.isfinite(focal) or focal <= 0:
        raise MessageError(f"camera info {msg.width}x{msg.height} with focal length {focal} "
                           "is unusable (need a positive size and focal length)")
    return CameraModel(width=int(msg.width), height=int(msg.height), focal_px=focal)


def poses_from_geometry(msg: StereoGeometry) -> tuple[EyePose, EyePose]:
    """Left and right eye poses of a StereoGeometry message. Raises MessageError on NaN."""
    def one(p):  # type: ignore[no-untyped-def]
        pose = msg_to_eye_pose(p)
        if not (np.all(np.isfinite(pose.position)) and np.all(np.isfinite(pose.rotation))):
            raise MessageError(f"stereo geometry of goal {msg.goal_id}: eye pose not finite")
        return pose
    return one(msg.left_eye), one(msg.right_eye)


def msg_to_haptic(msg: HapticReadingMsg) -> HapticReading:
    """A haptic message as a core reading.

    A reading without contact (the hand closed on nothing) carries NaN weight and is kept
    as it is. Raises MessageError on a contact with a NaN or negative weight or position.
    """
    if not msg.contact:
        return HapticReading(arm=int(msg.arm), contact=False,
                             position=point_tuple(msg.position), weight=float(msg.weight))
    if not math.isfinite(msg.weight) or msg.weight < 0:
        raise MessageError(f"haptic reading of goal {msg.goal_id}: weight {msg.weight} unusable")
    if not all(math.isfinite(v) for v in point_tuple(msg.position)):
        raise MessageError(f"haptic reading of goal {msg.goal_id}: position not finite")
    return HapticReading(arm=int(msg.arm), contact=bool(msg.contact),
                         position=point_tuple(msg.position), weight=float(msg.weight))


def roi_to_msg(roi: Roi) -> RoiMsg:
    """A core Roi as a message."""
    x0, y0, x1, y1 = roi.bbox
    return RoiMsg(id=int(roi.roi_id), x0=int(x0), y0=int(y0), x1=int(x1), y1=int(y1),
                  position=point(roi.position),
                  features=[float(v) for v in roi.features], known=[bool(k) for k in roi.known],
                  activation=float(roi.activation), retinal_size=float(roi.retinal_size),
                  mean_intensity=float(roi.mean_intensity), motion=float(roi.motion),
                  tactile=float(roi.tactile), mapped=bool(roi.mapped))


def msg_to_roi(msg: RoiMsg) -> Roi:
    """A Roi message as a core Roi. Raises MessageError on a malformed one."""
    features = np.asarray(msg.features, dtype=np.float32)
    known = np.asarray(msg.known, dtype=bool)
    if features.shape != (FEATURE_DIM,) or known.shape != (FEATURE_DIM,):
        raise MessageError(f"ROI {msg.id}: {features.size} features and {known.size} known "
                           f"flags, expected {FEATURE_DIM} each")
    if not np.all(np.isfinite(features)) or features.min() < -1e-6 or features.max() > 1 + 1e-6:
        raise MessageError(f"ROI {msg.id}: features outside [0, 1] or NaN")
    pos = point_tuple(msg.position)
    if not all(math.isfinite(v) for v in pos):
        raise MessageError(f"ROI {msg.id}: position {pos} is not finite")
    return Roi(roi_id=int(msg.id), bbox=(msg.x0, msg.y0, msg.x1, msg.y1), position=pos,
               features=features, known=known, activation=float(msg.activation),
               retinal_size=float(msg.retinal_size), mean_intensity=float(msg.mean_intensity),
               motion=float(msg.motion), tactile=float(msg.tactile), mapped=bool(msg.mapped))


def rois_to_msg(rois: list[Roi], stamp: float, goal_id: int) -> RoiArray:
    """All ROIs of one stereo pair."""
    return RoiArray(header=Header(stamp=seconds_to_time(stamp), frame_id="roger_base"),
                    goal_id=int(goal_id), rois=[roi_to_msg(r) for r in rois])


def msg_to_rois(msg: RoiArray) -> list[Roi]:
    """A RoiArray as core Rois (raises MessageError on the first malformed ROI)."""
    ids = [int(r.id) for r in msg.rois]
    if len(set(ids)) != len(ids):
        raise MessageError(f"ROI array of goal {msg.goal_id}: ROI ids repeat ({ids})")
    return [msg_to_roi(r) for r in msg.rois]


def mapped_positions(msg: SpatialMap) -> list[tuple[float, float, float]]:
    """Positions of the mapped entries of a spatial map (entries with NaN are skipped)."""
    return [p for p in (point_tuple(e.position) for e in msg.entries if e.mapped)
            if all(math.isfinite(v) for v in p)]
