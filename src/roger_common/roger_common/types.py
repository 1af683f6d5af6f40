"""Plain data types shared by the core of every Roger package.

No ROS here: these dataclasses are what the core modules take and return. The ROS
nodes convert them to and from messages in each package's ``conversions.py``.

Frames and units: the robot frame has its origin on the ground under Roger's body,
x forward, y to the left, z up; metres, kilograms, radians, seconds of simulated time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import Enum, IntEnum

import numpy as np

#: Layout of the feature vector of a region of interest (section 3.1 of the paper):
#: intensity I^(k), texture T^(k), stereo S^(k) for the three LoG resolutions k = 1, 2, 3
#: (equations 1-3), size D (equation 4) and weight W (equation 5).
FEATURE_NAMES: tuple[str, ...] = (
    "I1", "I2", "I3",
    "T1", "T2", "T3",
    "S1", "S2", "S3",
    "D",
    "W",
)
FEATURE_DIM: int = len(FEATURE_NAMES)
#: Index of the weight feature, unknown until a haptic improvement measured it.
WEIGHT_INDEX: int = FEATURE_NAMES.index("W")
#: Index of the size feature, unknown when the silhouette is cut (retina edge, occluder).
SIZE_INDEX: int = FEATURE_NAMES.index("D")

#: Shape evidence beyond equations 1-5 (docs/perception.md, "Extended features"), appended
#: after W so that the paper's eleven keep their indices. From the retina, the stereo
#: position and the known camera geometry: H the height of the object's top above the
#: ground. From the fovea of a visual improvement (unknown before one): O how far the top
#: outline departs from the ellipse a vertical cylinder's rim would project. A the grey of
#: the brightest surface in the retina (a flat top's, lit alike wherever it stands). AS the
#: albedo the silhouette's shading gives if the object is a sphere under the known light
#: (a sphere's reads alike from every place; the memory compares it between two looks the
#: hand found curved, and vetoes there). From touch (unknown, like W, until a haptic
#: improvement): TH the height of the top the hand
#: touched, TK the curvature its touches agree on (0 on a flat top or a flank, 1 / radius
#: on a sphere), TC the crease between them that the curvature does not explain (a
#: prism's ridge) and TR the curvature of a flat top's rim the tactile array felt under the
#: pad (0 for a box's straight edge, 2 / size for a cylinder's; unknown where no touch
#: reached over a rim). From sight and touch together (unknown until a haptic improvement
#: touched a sloped face and crossed a crease: a prism): AP the albedo the silhouette's
#: shading gives under the known light for the faces the touched flanks' normals say.
SHAPE_FEATURE_NAMES: tuple[str, ...] = ("H", "O", "A", "AS", "TH", "TK", "TC", "TR", "AP")
#: The features a haptic improvement measures (unknown before one): W, touch's shape and
#: the albedo of the faces it touched.
TOUCH_FEATURE_NAMES: tuple[str, ...] = ("W", "TH", "TK", "TC", "TR", "AP")
#: The features only a visual improvement's foveal look measures (unknown before one).
FOVEA_FEATURE_NAMES: tuple[str, ...] = ("O",)


class FeatureMode(str, Enum):
    """Which features perception computes and the memory compares.

    PAPER: the eleven of equations 1-5 (FEATURE_NAMES), the reproduction mode.
    EXTENDED: those eleven, then SHAPE_FEATURE_NAMES (the documented extension).
    """

    PAPER = "paper"
    EXTENDED = "extended"

    @classmethod
    def parse(cls, value: str | FeatureMode) -> FeatureMode:
        """The mode named ``value``; ValueError naming the choices otherwise."""
        try:
            return cls(value)
        except ValueError:
            raise ValueError(f"feature mode {value!r}: expected one of "
                             f"{[m.value for m in cls]}") from None


#: The mode a run uses unless told otherwise.
DEFAULT_FEATURE_MODE: FeatureMode = FeatureMode.EXTENDED


def feature_names(mode: FeatureMode | str) -> tuple[str, ...]:
    """The feature vector's layout in ``mode``: the paper's eleven, then the extension."""
    if FeatureMode.parse(mode) is FeatureMode.PAPER:
        return FEATURE_NAMES
    return FEATURE_NAMES + SHAPE_FEATURE_NAMES


def feature_dim(mode: FeatureMode | str) -> int:
    """Length of the feature vector in ``mode``."""
    return len(feature_names(mode))


def mode_of_dim(n: int) -> FeatureMode:
    """The mode whose feature vector has ``n`` entries; ValueError for any other length."""
    for mode in FeatureMode:
        if feature_dim(mode) == n:
            return mode
    raise ValueError(f"{n} features: expected {[feature_dim(m) for m in FeatureMode]} "
                     f"({[m.value for m in FeatureMode]})")


class Action(IntEnum):
    """The four actions of section 4.2; one control cycle executes exactly one."""

    ATTENTION_SHIFT = 0
    VISUAL_IMPROVEMENT = 1
    HAPTIC_IMPROVEMENT = 2
    MAP_UPDATE = 3


#: Actions that move a controller (a map update is bookkeeping only).
PHYSICAL_ACTIONS: frozenset[Action] = frozenset(
    {Action.ATTENTION_SHIFT, Action.VISUAL_IMPROVEMENT, Action.HAPTIC_IMPROVEMENT}
)


class ControllerState(IntEnum):
    """Status of one servo controller, as the original Roger simulator reported it."""

    NO_REFERENCE = 0
    TRANSIENT = 1
    CONVERGED = 2
    FAILED = 3


class MatchOutcome(IntEnum):
    """Result of a match in the associative memory (section 4.2, cases a-c)."""

    IDENTIFIED = 0
    NEW = 1
    UNDETERMINED = 2


@dataclass(frozen=True)
class Goal:
    """A physical action for the simulator to execute.

    Attributes:
        goal_id: Unique, increasing id; every reply (convergence, frames) carries it.
        action: One of the physical actions (never MAP_UPDATE).
        target: Point to look at or to reach, robot frame, metres.
        arm: For a haptic improvement: 0 left, 1 right, -1 let the simulator choose
            (the arm on the target's side).
    """

    goal_id: int
    action: Action
    target: tuple[float, float, float]
    arm: int = -1


@dataclass(frozen=True)
class HapticReading:
    """What an arm felt during a haptic improvement.

    Attributes:
        arm: 0 left, 1 right.
        contact: True when the hand touched an object.
        position: Where the hand touched it, robot frame, metres.
        weight: Measured weight in kilograms (noisy); NaN without contact.
        contacts: Every touch of the hand's tactile sensor in this improvement, in order:
            the first touch (at ``position``) and the probe touches around it, as a
            tactile sensor reports them (contact point and the surface normal there).
            Empty when the hand touched nothing.
    """

    arm: int
    contact: bool
    position: tuple[float, float, float]
    weight: float
    contacts: tuple[TactileContact, ...] = ()


@dataclass(frozen=True)
class TactileContact:
    """One touch of the hand's tactile sensor.

    Attributes:
        point: The contact point on the touched surface, robot frame, metres.
        normal: Unit normal of the touched surface there, pointing out of it (up, on a
            top face), robot frame.
        probe: Horizontal offset of the hand from the first touch when it touched,
            robot frame (dx, dy), metres; (0, 0) for the first touch.
        image: The tactile array's image of the touch: ``taxels`` x ``taxels`` values, row
            by row in the pad's own frame, each the depth of the surface below the flat
            pad at that taxel, metres (negative: pressed into the skin), NaN where no
            surface lies within the skin's range (no pressure there); empty without an
            array.
        pitch: Distance between two neighbouring taxels, metres; 0 without an array.
    """

    point: tuple[float, float, float]
    normal: tuple[float, float, float]
    probe: tuple[float, float] = (0.0, 0.0)
    image: tuple[float, ...] = ()
    pitch: float = 0.0

    @property
    def taxels(self) -> int:
        """Taxels along each side of the image (0 without one)."""
        return int(round(math.sqrt(len(self.image))))


@dataclass(frozen=True)
class ControllerReport:
    """Status of the five controllers after a goal, plus how long they took.

    Attributes:
        goal_id: The goal.
        states: Status of every controller (a FAILED one stays FAILED until it gets a new
            reference, as Roger's controllers reported it).
        sim_time: Simulated time at the end of the goal.
        physics_steps: Physics steps the goal took.
        driven: The controllers the goal drove; empty: all of them.
    """

    goal_id: int
    states: dict[str, ControllerState]
    sim_time: float
    physics_steps: int
    driven: tuple[str, ...] = ()

    @property
    def converged(self) -> bool:
        """True when none of the controllers the goal drove failed or is still transient
        (an arm that failed an earlier goal does not fail this one)."""
        names = self.driven or tuple(self.states)
        return all(
            self.states[n] in (ControllerState.CONVERGED, ControllerState.NO_REFERENCE)
            for n in names
        )


@dataclass(frozen=True)
class CameraModel:
    """Pinhole model of one retina.

    Attributes:
        width, height: Image size in pixels.
        focal_px: Focal length in pixels (fx = fy); principal point at the centre.
    """

    width: int
    height: int
    focal_px: float


@dataclass(frozen=True)
class EyePose:
    """Pose of one eye's camera in the robot frame.

    Attributes:
        position: Optical centre, metres.
        rotation: 3x3 matrix whose columns are the camera axes in the robot frame,
            OpenCV convention: column 0 = image right (+u), column 1 = image down (+v),
            column 2 = optical axis (forward).
        quaternion: The unit quaternion (x, y, z, w) ``rotation`` was computed from, when
            it was (``geometry.eye_pose``): messages carry it, so that a receiver rebuilds
            ``rotation`` bit for bit and the graph computes what the core loop computes.
    """

    position: np.ndarray
    rotation: np.ndarray
    quaternion: tuple[float, float, float, float] | None = None


@dataclass
class StereoFrame:
    """One stereo pair from the retinas, with the geometry needed to triangulate.

    Attributes:
        stamp: Simulated time of the render, seconds.
        goal_id: Goal after whose convergence the frame was rendered (0: none yet).
        left, right: Retinal intensity images, float32 in [0, 1], shape (H, W).
        camera: Intrinsics shared by both eyes.
        left_pose, right_pose: Extrinsics of each eye.
        exposures: How many renders were averaged into the images (a visual
            improvement integrates several, which lowers pixel noise).
        haptic: Reading of the last haptic improvement for this goal, if any.
        left_labels, right_labels: Ground truth only (evaluation, never policy or
            memory): per pixel, the index into ``label_names`` of the object seen,
            -1 for the ground and the robot itself.
        label_names: Object names for the label images.
        fovea: After a visual improvement, the left eye's foveal image: the centre of
            its field at a higher resolution (``SimConfig.fovea_fov_deg``), float32 in
            [0, 1], same pose as ``left``, with its own pixel noise; None otherwise.
        fovea_camera: Intrinsics of ``fovea`` (None without one).
        fovea_right: The right eye's fovea of the same look (same intrinsics, the right
            eye's pose, its own pixel noise), when the simulator renders both
            (``SimConfig.fovea_stereo``); None otherwise.
    """

    stamp: float
    goal_id: int
    left: np.ndarray
    right: np.ndarray
    camera: CameraModel
    left_pose: EyePose
    right_pose: EyePose
    exposures: int = 1
    haptic: HapticReading | None = None
    left_labels: np.ndarray | None = None
    right_labels: np.ndarray | None = None
    label_names: tuple[str, ...] = ()
    fovea: np.ndarray | None = None
    fovea_camera: CameraModel | None = None
    fovea_right: np.ndarray | None = None


@dataclass
class Roi:
    """A region of interest of the perceptual buffer (section 2 of the paper).

    Attributes:
        roi_id: Id unique within one ROI array (not across frames: the spatial map
            associates ROIs across frames by position).
        bbox: (u0, v0, u1, v1) in the left retina, pixels, u1/v1 exclusive: the attention
            window, the box of the ROI's pixels where its object is seen (above the
            ground's noise; roger_perception.segmentation.window_boxes). The ROI's label
            image may reach a pixel of rim or a ground seam beyond it.
        position: Estimated centre in the robot frame from stereo, metres.
        features: FEATURE_DIM floats in [0, 1] (see FEATURE_NAMES).
        known: FEATURE_DIM booleans; False where a feature is not measured yet
            (the weight before a haptic improvement). Unknown features hold 0.
        activation: Pre-attentive activation in [0, 1].
        retinal_size: Share of the retina the ROI covers, [0, 1].
        mean_intensity: Average retinal intensity in the ROI, [0, 1].
        motion: Visual motion since the previous frame, [0, 1].
        tactile: Tactile response (1 when a hand touches it), [0, 1].
        mapped: Mapping status of the spatial-map entry at this position.
        cut: True when the ROI touches the edge of the left retina: part of the object
            lies outside the view, so its position (and size) are estimates that move as
            the gaze moves; trust it less than an uncut ROI's.
        size_m: Metric size of what the retina shows of it: the side of a square of its
            silhouette's area at its depth, metres (for a cut or occluded ROI, of the part
            in view; the feature D is then unknown).
    """

    roi_id: int
    bbox: tuple[int, int, int, int]
    position: tuple[float, float, float]
    features: np.ndarray
    known: np.ndarray
    activation: float = 0.0
    retinal_size: float = 0.0
    mean_intensity: float = 0.0
    motion: float = 0.0
    tactile: float = 0.0
    mapped: bool = False
    cut: bool = False
    size_m: float = 0.0


@dataclass(frozen=True)
class MatchResult:
    """Answer of the associative memory to a match request.

    Attributes:
        outcome: IDENTIFIED, NEW or UNDETERMINED.
        address: Long-term-memory address of the winner; -1 when none.
        confidence: Winner-take-all confidence in [0, 1].
    """

    outcome: MatchOutcome
    address: int = -1
    confidence: float = 0.0


class MemoryOp(IntEnum):
    """What the attention node asks of the associative memory."""

    MATCH = 0
    STORE = 1


@dataclass(frozen=True)
class MemoryRequest:
    """A match or a store (supervised learning of a new object).

    Attributes:
        request_id: Echoed in the reply.
        op: MATCH or STORE.
        features: FEATURE_DIM floats in [0, 1].
        known: FEATURE_DIM booleans; unknown features are ignored, not taken as 0.
        final_trial: For MATCH: all improvement trials are used up, so the memory must
            decide between IDENTIFIED and NEW (UNDETERMINED only for a look that
            knows too few features to be compared with anything, docs/memory.md).
        focus_id: The focus (attention shift) the features were taken in; the memory
            groups the looks of one focus by it (a STORE keeps them all). 0: unknown.
    """

    request_id: int
    op: MemoryOp
    features: np.ndarray
    known: np.ndarray
    final_trial: bool = False
    focus_id: int = 0


@dataclass
class RunCounters:
    """The counters of Table 2, kept so that its two identities hold by construction:

    attention_shifts + improvements + map_updates == cycles, and
    map_updates == positive_identifications + new_objects + remaps.

    A positive identification is the identification that maps an entry (a place of the
    spatial map) not mapped before; an identification that maps again an entry that was
    mapped and lost its mapping since (it drifted, was contradicted, or was lost from the
    map and seen again at its place) is a remap.
    """

    cycles: int = 0
    attention_shifts: int = 0
    visual_improvements: int = 0
    haptic_improvements: int = 0
    positive_identifications: int = 0
    new_objects: int = 0
    map_updates: int = 0
    remaps: int = 0

    @property
    def improvements(self) -> int:
        """Eye and arm improvements together (Table 2's 'Eye/Arm Improv')."""
        return self.visual_improvements + self.haptic_improvements

    def as_dict(self) -> dict[str, int]:
        """All counters, derived ones included, by name."""
        return {
            "cycles": self.cycles,
            "attention_shifts": self.attention_shifts,
            "improvements": self.improvements,
            "visual_improvements": self.visual_improvements,
            "haptic_improvements": self.haptic_improvements,
            "positive_identifications": self.positive_identifications,
            "new_objects": self.new_objects,
            "map_updates": self.map_updates,
            "remaps": self.remaps,
        }


@dataclass(frozen=True)
class ObjectSpec:
    """One object of a world file (see docs/world-files.md for the schema)."""

    name: str
    shape: str
    position: tuple[float, float]
    size: float
    intensity: float
    weight: float
    yaw: float = 0.0
    texture: str = "plain"

    def category(self) -> tuple[str, float, float, float, str]:
        """Objects with the same shape, size, intensity, weight and texture are one category."""
        return (self.shape, round(self.size, 6), round(self.intensity, 6),
                round(self.weight, 6), self.texture)


@dataclass(frozen=True)
class WorldSpec:
    """A whole world file."""

    objects: tuple[ObjectSpec, ...]
    name: str = "world"
    light_direction: tuple[float, float, float] = (1.0, 0.5, 1.0)
    source: str = "<memory>"




@dataclass
class Rngs:
    """Seeded generators handed to the core; no module-global randomness anywhere."""

    seed: int
    numpy: np.random.Generator = field(init=False)

    def __post_init__(self) -> None:
        self.numpy = np.random.default_rng(self.seed)

    def child(self, name: str) -> np.random.Generator:
        """An independent generator for one component, stable for a given seed and name."""
        salt = sum((i + 1) * ord(c) for i, c in enumerate(name))
        return np.random.default_rng([self.seed, salt])
