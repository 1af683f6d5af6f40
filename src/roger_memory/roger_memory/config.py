"""Parameters of the associative memory: network sizes, replay training and match thresholds.

Every default is explained in docs/memory.md. Values flow one way: ROS parameters ->
MemoryConfig -> AssociativeMemory.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields
from typing import Any, NoReturn

from roger_common.errors import ConfigError
from roger_common.types import (
    DEFAULT_FEATURE_MODE,
    FOVEA_FEATURE_NAMES,
    TOUCH_FEATURE_NAMES,
    FeatureMode,
    feature_names,
)

#: Fields that fix the shape of the network; a memory file is only compatible with a
#: configuration that agrees on them: the feature mode (the length and meaning of every
#: look). The radial network's other dimensions are the stored looks.
ARCHITECTURE_FIELDS: tuple[str, ...] = ("features",)

#: Calibration of the shipped defaults (docs/memory.md, "Calibration"): measured by
#: roger_memory.calibration.calibrate on test/data/memory_queries.csv.gz, the robot's own
#: looks at the six shipped worlds, without their labels; test_memory_recorded.py
#: (test_the_shipped_calibration_is_what_the_recorded_looks_give) checks that the file
#: still gives these values.
CALIBRATED_FEATURE_SCALE: tuple[float, ...] = (
    0.02451, 0.03266, 0.04142, 0.00482, 0.00397, 0.00432,
    0.02929, 0.02667, 0.03053, 0.00466, 0.01058)
CALIBRATED_FEATURE_WEIGHT: tuple[float, ...] = (
    1.525, 1.235, 0.942, 0.452, 0.527, 0.594,
    0.573, 0.489, 0.062, 1.642, 2.959)
CALIBRATED_IDENTIFY_DISTANCE: float = 2.01
CALIBRATED_VETO: tuple[float, ...] = (
    0.1276, 0.1816, 0.2791, 0.0392, 0.0305, 0.0376,
    0.2578, 0.2195, 0.2638, 0.0372, 0.0492)
CALIBRATED_NOISE_DOF: float = 6.32

#: The extended mode's calibration (FEATURE_NAMES then SHAPE_FEATURE_NAMES), measured the
#: same way on test/data/memory_queries_extended.csv.gz: the robot's own extended looks at
#: five shipped worlds (not inspection) and three random ones (worldgen seed 900: plain,
#: shape_twins, yaw_copies), both policies, seed 0 (docs/memory.md, "Calibration").
EXTENDED_FEATURE_SCALE: tuple[float, ...] = (
    0.02630, 0.03939, 0.04737, 0.00527, 0.00589, 0.00554,
    0.02969, 0.02559, 0.02448, 0.00461, 0.01060, 0.02827,
    0.01599, 0.01371, 0.01954, 0.00128, 0.00521, 0.02547,
    0.01966, 0.00393)
EXTENDED_FEATURE_WEIGHT: tuple[float, ...] = (
    1.545, 1.170, 0.995, 0.514, 0.426, 0.465,
    0.411, 0.332, 0.048, 1.700, 3.019, 0.511,
    1.404, 1.579, 1.432, 0.792, 0.172, 0.394,
    2.434, 0.655)
EXTENDED_IDENTIFY_DISTANCE: float = 2.30
#: The extended mode's features that vary with the view: the paper's I, T and S (shading
#: with bearing, relief with distance, both with yaw) and the fovea's outline O (a prism's
#: reads 0.18-0.56 over yaws). A fixed robot sees each object from one place, so two
#: copies seen from two places differ in them by more than one object's own looks ever
#: do, and a veto measured on those looks turned copies away (docs/memory.md, "Only
#: view-invariant features veto"). They still count in every distance, capped; only
#: D, W and the 3-D and touch features (H, TH, TK, TR) may veto.
#: A (the brightest surface's grey) is view dependent for a sphere and a prism (their
#: brightest visible surface turns with bearing and yaw), not for a flat top. AS (the
#: albedo a sphere's normals give the shading) is view dependent for every other shape;
#: between two looks the hand found curved it vetoes (CURVED_VETO_FEATURES). AP (the albedo
#: the touched flanks' normals give the shading) is known only where the touches crossed
#: a crease on a sloped face (a prism's), and reads alike at every yaw and place there: it
#: vetoes (docs/perception.md, "A prism's albedo (AP)").
VIEW_DEPENDENT_FEATURES: tuple[str, ...] = ("I1", "I2", "I3", "T1", "T2", "T3",
                                            "S1", "S2", "S3", "O", "A", "AS")
#: Touch features whose reading can miss what it measures: a haptic reading whose probes
#: all stay on one flank of a prism finds no crease (TC 0, where the prism's other
#: readings give 1; the median outvotes it once the object has been touched three
#: times). A crease found is evidence of a crease, none found is not evidence of none,
#: so TC's difference never vetoes; it counts in the distance. Its calibrated veto, the
#: 99.9th percentile of one object's own repeats, depends on whether a recording caught
#: such a reading (2.14 on the 2641-look recording, 0.23 on the 2700-look one, where it
#: stored prism copies again in closed loop: docs/memory.md, "A missed crease").
MISSABLE_FEATURES: tuple[str, ...] = ("TC",)
#: Features measured on flat tops only, that veto between two flat looks alone
#: (FLAT_VETO_FEATURES): TR, the curvature of the rim the tactile array felt (0 on a box's
#: straight edge, 2 / size on a cylinder's; unknown on spheres and prisms, whose tops do
#: not lie flat under the pad). Every look of an object carries the rims of its last
#: readings, so two looks of one entry nearly always share one value and its repeats
#: measure no noise: scaled from that to the category spread (the general veto) it read
#: 33.6 on the first recording with it, beyond its range (docs/memory.md, "A flat top's
#: rim").
FLAT_ONLY_FEATURES: tuple[str, ...] = ("TR",)
#: The extended mode's features that never veto (``calibration.calibrate``'s
#: ``vetoing`` is every other feature); FLAT_ONLY_FEATURES veto between flat looks.
NEVER_VETO_FEATURES: tuple[str, ...] = (VIEW_DEPENDENT_FEATURES + MISSABLE_FEATURES
                                        + FLAT_ONLY_FEATURES)
#: NEVER_VETO_FEATURES' vetoes are NO_VETO (1.0: no difference of features in [0, 1]
#: exceeds it). TK's lay beyond that range until TK was measured on smooth surfaces only
#: (1.26 before, a prism's edge reading taken for a curve); now it vetoes.
EXTENDED_VETO: tuple[float, ...] = (
    1.0, 1.0, 1.0, 1.0, 1.0, 1.0,
    1.0, 1.0, 1.0, 0.0406, 0.0493, 0.2311,
    1.0, 1.0, 1.0, 0.0252, 0.3624, 1.0,
    1.0, 0.0284)
EXTENDED_NOISE_DOF: float = 4.41
#: The features that veto between two looks the hand found smooth and flat
#: (``MemoryConfig.flat_veto``): the fovea's outline O. A flat top's outline is the same
#: from every place (a cylinder's rim is the ellipse the outline is measured against, a
#: box reads 0.14-0.19 at every yaw, since O counts up to a straight edge's departure:
#: docs/memory.md, "O up to a straight edge's departure"), unlike a prism's (its ridge
#: turns with the yaw) or a
#: sphere's (its outline against the rim's ellipse changes with the declination), and it
#: is the one feature that parts a box from a cylinder of one size, grey and weight
#: (docs/memory.md, "The outline vetoes between flat tops"). And A: a flat top's grey
#: under the one light is the same from every place (docs/perception.md, "The brightest
#: surface's grey").
FLAT_VETO_FEATURES: tuple[str, ...] = ("O", "A") + FLAT_ONLY_FEATURES
#: The extended mode's veto between two flat looks: NO_VETO (1.0) but for
#: FLAT_VETO_FEATURES, calibrated on the same looks (``calibration.calibrate``'s
#: ``flat_veto``).
EXTENDED_FLAT_VETO: tuple[float, ...] = (
    1.0, 1.0, 1.0, 1.0, 1.0, 1.0,
    1.0, 1.0, 1.0, 1.0, 1.0, 1.0,
    0.0706, 0.0754, 1.0, 1.0, 1.0, 1.0,
    0.1236, 1.0)
#: The features that veto between two flat looks whose outlines are both straight-edged
#: (``MemoryConfig.straight_veto``): A. A box's top is one grey under the one light
#: wherever it stands (copies within 0.002-0.008 of each other), where a cylinder's
#: brightest surface is its lit side, which turns with its bearing (copies 0.018-0.028
#: apart), and that spread is what widens A's veto between flat tops to 0.093 (docs/memory.md,
#: "The grey between two straight-edged tops").
STRAIGHT_VETO_FEATURES: tuple[str, ...] = ("A",)
#: The outline O from which a flat look's top counts as straight-edged: the two-class split
#: (``calibration.two_class_split``) of the flat looks' O on the same recorded looks (boxes
#: read 0.10-0.19, cylinders 0.02-0.09 there).
EXTENDED_STRAIGHT_OUTLINE: float = 0.1261
#: The extended mode's veto between two straight-edged flat looks: NO_VETO (1.0) but for
#: STRAIGHT_VETO_FEATURES, calibrated on those looks alone (``calibration.calibrate``'s
#: ``straight_veto``).
EXTENDED_STRAIGHT_VETO: tuple[float, ...] = (
    1.0, 1.0, 1.0, 1.0, 1.0, 1.0,
    1.0, 1.0, 1.0, 1.0, 1.0, 1.0,
    1.0, 0.0196, 1.0, 1.0, 1.0, 1.0,
    1.0, 1.0)
#: The features that veto between two looks the hand found smooth and curved
#: (``MemoryConfig.curved_veto``: TC < ``flat_crease``, TK >= ``flat_curvature``, a
#: sphere): AS. A sphere's albedo under the known light reads alike from every place
#: (sd 2-2.5 % of the albedo over bearings -60 to +60 degrees and 0.5-1 m), where its
#: brightest grey A turns with the lit cap it shows (sd 6-7 %): two sphere categories of
#: one size and weight a Table-1 grey step apart (72 and 87) were taken for each other
#: on random 10058 (docs/memory.md, "A sphere's albedo").
CURVED_VETO_FEATURES: tuple[str, ...] = ("AS",)
#: The extended mode's veto between two curved looks: NO_VETO (1.0) but for
#: CURVED_VETO_FEATURES, calibrated on those looks alone (``calibration.calibrate``'s
#: ``curved_veto``).
EXTENDED_CURVED_VETO: tuple[float, ...] = (
    1.0, 1.0, 1.0, 1.0, 1.0, 1.0,
    1.0, 1.0, 1.0, 1.0, 1.0, 1.0,
    1.0, 1.0, 0.0395, 1.0, 1.0, 1.0,
    1.0, 1.0)
#: The features left out of the distance between two looks whose touches crossed a
#: crease (TC >= ``MemoryConfig.flat_crease``: a prism's ridge): the fovea's outline O,
#: which for a creased object turns with its yaw (a prism's reads 0.2-0.85) and so says
#: nothing of its category between two of them, where between a box and a cylinder it is
#: the one feature that parts them (docs/memory.md, "The outline between two creased
#: looks"). And the brightest surface's grey A: a creased object's faces are flat and
#: turn with its yaw against the one light, so its brightest face's grey does (a prism's
#: A 0.03-0.1 apart between copies), where a box's top keeps its grey. (The paper's rim
#: contrast I1-I3 turns too, but between two prisms it still parts categories: left out
#: as well, 5 of 225 pairs of two categories' creased looks fell within the acceptance
#: distance, none with A alone; docs/memory.md, "The brightest grey between two creased
#: looks".) Since 2026-11-29 I1-I3 and T1-T3 are left out too: AP, the albedo of the faces
#: the hand touched, carries a prism's grey at every yaw, where the rim contrast and the
#: texture of its lit flank turn with it (17 of 23 copies on random 10142-10143 were
#: prisms beyond tau by I and T; docs/memory.md, "A prism's albedo").
CREASED_UNUSED_FEATURES: tuple[str, ...] = ("O", "A", "I1", "I2", "I3", "T1", "T2", "T3")
#: The extended mode caps each feature's |z| at 4.5 in every distance (MemoryConfig.z_cap),
#: the cap ``calibration.choose_z_cap`` picks from the same looks: of the caps 0-8, the
#: one whose acceptance distance (95 % of the robot's own repeats) takes in the fewest
#: looks of other map entries (docs/memory.md, "A robust distance").
EXTENDED_Z_CAP: float = 4.5


@dataclass(frozen=True)
class Calibrated:
    """One feature mode's calibrated defaults (see MemoryConfig for each field)."""

    feature_scale: tuple[float, ...]
    feature_weight: tuple[float, ...]
    identify_distance: float
    veto: tuple[float, ...]
    noise_dof: float
    maskable_features: tuple[str, ...]
    z_cap: float
    flat_veto: tuple[float, ...]
    straight_outline: float
    straight_veto: tuple[float, ...]
    curved_veto: tuple[float, ...]


#: The calibrated defaults of each feature mode.
CALIBRATED: dict[FeatureMode, Calibrated] = {
    FeatureMode.PAPER: Calibrated(CALIBRATED_FEATURE_SCALE, CALIBRATED_FEATURE_WEIGHT,
                                  CALIBRATED_IDENTIFY_DISTANCE, CALIBRATED_VETO,
                                  CALIBRATED_NOISE_DOF, ("W",), 0.0,
                                  (1.0,) * len(CALIBRATED_VETO), 1.0,
                                  (1.0,) * len(CALIBRATED_VETO),
                                  (1.0,) * len(CALIBRATED_VETO)),
    FeatureMode.EXTENDED: Calibrated(EXTENDED_FEATURE_SCALE, EXTENDED_FEATURE_WEIGHT,
                                     EXTENDED_IDENTIFY_DISTANCE, EXTENDED_VETO,
                                     EXTENDED_NOISE_DOF,
                                     TOUCH_FEATURE_NAMES + FOVEA_FEATURE_NAMES,
                                     EXTENDED_Z_CAP, EXTENDED_FLAT_VETO,
                                     EXTENDED_STRAIGHT_OUTLINE, EXTENDED_STRAIGHT_VETO,
                                     EXTENDED_CURVED_VETO),
}
_DEFAULT = CALIBRATED[DEFAULT_FEATURE_MODE]


@dataclass(frozen=True)
class MemoryConfig:
    """Configuration of :class:`roger_memory.memory.AssociativeMemory`.

    The calibrated fields (``feature_scale``, ``feature_weight``, ``identify_distance``,
    ``veto``, ``noise_dof``, ``maskable_features``) default to the calibration of the
    default feature mode; in a config of another mode, each calibrated field left at a
    mode's calibration takes that mode's (``CALIBRATED``), so ``MemoryConfig(features=
    "paper", veto=...)`` is the paper's calibration with your veto.

    Attributes:
        features: Feature mode of the vectors the memory compares: "paper" (FEATURE_NAMES,
            equations 1-5) or "extended" (those, then SHAPE_FEATURE_NAMES). A memory file
            of one mode is refused by a memory of the other.
        feature_scale: Per feature (``feature_names(features)`` order), the spread
            sigma_f of one look of a category around another look of it (calibrated,
            docs/memory.md); the initial scale of the network's radial units.
        feature_weight: Per feature, the weight of its z_f^2 in every distance: its
            information, log(spread between entries / sigma_f), mean 1 (calibrated); 0
            leaves a feature out of the distance (it still counts towards
            ``min_common_features``).
        identify_distance: Acceptance distance tau: the weighted RMS over the common known
            features of z_f = difference / (sqrt(2) sigma_f) within which a look counts as
            a repeat (calibrated); the initial bias of the network's novel unit.
        noise_dof: Degrees of freedom of the Student-t repeat noise the replay adds
            (calibrated: the heaviness of the tail of the robot's own repeat looks).
        veto: Per feature, the largest difference between a query and the winner's nearest
            look that can still be an identification (calibrated: never seen between two
            looks of one object); a larger one vetoes the network's identification.
        flat_veto: Per feature, the veto between a query and the winner's nearest look when
            the hand found both smooth and flat-topped (TC < ``flat_crease``, TK <
            ``flat_curvature``, both known in both; extended mode): the smaller of this and
            ``veto`` applies (calibrated; 1.0, no veto, for all but FLAT_VETO_FEATURES).
        flat_crease: Largest crease TC of a smooth top (TC reads 1 on a prism, whose
            touches always cross its ridge, and under 0.2 on everything else the robot
            touched).
        flat_curvature: Largest curvature TK of a flat top (a sphere reads 0.3-0.8, a box's
            or cylinder's top under 0.05).
        straight_outline: Smallest outline O of a straight-edged flat top (a box's reads
            0.10-0.19, a cylinder's 0.02-0.09; calibrated: the two-class split of the flat
            looks' O).
        straight_veto: Per feature, the veto between a query and the winner's nearest look
            when both are flat and both outlines are straight-edged (O known and at least
            ``straight_outline`` in both; extended mode): the smallest of this,
            ``flat_veto`` and ``veto`` applies (calibrated; 1.0 for all but
            STRAIGHT_VETO_FEATURES).
        curved_veto: Per feature, the veto between a query and the winner's nearest look
            when the hand found both smooth and curved (TC < ``flat_crease``, TK at least
            ``flat_curvature``, both known in both: a sphere; extended mode): the smaller
            of this and ``veto`` applies (calibrated; 1.0 for all but
            CURVED_VETO_FEATURES).
        creased_unused: Features left out of the distance between two looks whose touches
            found a crease (TC >= ``flat_crease``, known in both; extended mode: O, which
            turns with a prism's yaw; () in the paper mode, which has no crease; () in the
            extended mode turns the rule off). Everywhere else they count.
        min_common_features: Fewest features known both in the query and in a stored look
            for that look's unit to answer.
        identify_share: Smallest winner-take-all share of the winning address for a
            non-final identification.
        veto_any_look: The winner passes the veto when one of its looks that can answer
            the query (``min_common_features`` in common) and compares every feature some
            look of the address compares with it is within every veto: the object was
            seen that way. False: its nearest look alone decides, even one that never
            measured the feature that would veto (before 2026-11-28).
        crease_found_veto: A query whose touches found a crease (TC >= ``flat_crease``)
            and felt no flat top's rim (TR unknown) is not an address none of whose looks
            found one, though at least one of them measured TC (extended mode). One-sided:
            a crease found is evidence of an edge (a ridge under the pad or two normals 45
            degrees apart), none found is not evidence of none (the probes may stay on one
            flank), so a query that found no crease is never vetoed by it. And a flat top's
            rim is a crease too (a cylinder touched at the edge of reach, its probes over
            the rim): a query whose pad lay flat over a rim (TR known) is not either.
        rim_found_veto: Its mirror (extended mode): a query whose pad lay flat over a
            top's rim (TR known) and whose touches found no crease (TC < ``flat_crease``)
            is not an address every one of whose looks that measured TC found a crease
            and felt no rim (a prism: its top never lies flat under the pad). A rim felt
            is evidence of a flat top, as a crease found is of an edge.
        veto_rerun: After a veto, inhibit the vetoed winner and let the winner-take-all run
            again, once, over the units left; the next address wins if the veto lets it
            pass, with its share renormalised over the units left. False: a veto makes the
            look new (final trial).
        refine_looks: Looks an address may hold at most (its store's looks plus looks of
            later identifications of it, see docs/memory.md).
        learning_rate: Adam step size of the supervised learning module.
        batch_size: Samples per replay step.
        train_steps: Replay steps always taken after a store (a fixed budget, so that a
            store costs about the same at 10 and at 1,000 objects).
        check_every: After ``train_steps``, training goes on in blocks of this many steps
            until every stored look is recalled (see ``recall_confidence``).
        max_train_steps: Cap on the replay steps of one store.
        recall_confidence: A stored look counts as recalled (ending training) when, with
            its own known mask, its address wins with at least this softmax share.
        new_fraction: Share of the repeats of each replay batch drawn from the address
            being learned; the rest replays every stored look uniformly.
        novel_fraction: Share of each replay batch that is synthetic novel samples (the
            novel unit's target).
        novel_near: Novel samples lie at least this many times tau from a stored look.
        novel_far: Novel samples lie at most this many times tau from a stored look.
        prior_weight: Weight of the pull of centres towards their stored looks and of the
            scales and tau towards the calibration.
        unknown_feature_prob: Probability that a replayed sample has each feature named
            in ``maskable_features`` turned unknown, so that the network also answers
            before a haptic improvement.
        maskable_features: Features that may be unknown at match time (FEATURE_NAMES).
        z_cap: When > 0, each feature's |z_f| counts at most this much in every distance
            (the units' activation, the store's and refinement's acceptance, the
            calibration's): one feature that varies with the view more than the calibrated
            scale says (a prism's shading at another yaw) cannot reject a look alone; the
            veto still can. 0: the plain weighted RMS (the paper mode's).
    """

    features: str = field(default=DEFAULT_FEATURE_MODE.value, metadata={
        "doc": "Feature mode: paper (eqs. 1-5) or extended (+ shape from stereo and touch)"})
    feature_scale: tuple[float, ...] = field(default=_DEFAULT.feature_scale, metadata={
        "doc": "Calibrated spread of one look of a category, per feature"})
    feature_weight: tuple[float, ...] = field(default=_DEFAULT.feature_weight, metadata={
        "doc": "Calibrated information weight of each feature in the distance"})
    identify_distance: float = field(default=_DEFAULT.identify_distance, metadata={
        "doc": "Calibrated acceptance distance tau (weighted RMS z over common features)"})
    noise_dof: float = field(default=_DEFAULT.noise_dof, metadata={
        "doc": "Calibrated Student-t degrees of freedom of the replay noise"})
    veto: tuple[float, ...] = field(default=_DEFAULT.veto, metadata={
        "doc": "Calibrated largest per-feature difference of an identification",
        "live": True})
    flat_veto: tuple[float, ...] = field(default=_DEFAULT.flat_veto, metadata={
        "doc": "Calibrated veto between two looks of smooth flat tops, per feature",
        "live": True})
    flat_crease: float = field(default=0.5, metadata={
        "doc": "Largest touch crease TC of a smooth top (flat_veto)", "live": True})
    flat_curvature: float = field(default=0.2, metadata={
        "doc": "Largest touch curvature TK of a flat top (flat_veto)", "live": True})
    straight_outline: float = field(default=_DEFAULT.straight_outline, metadata={
        "doc": "Calibrated smallest outline O of a straight-edged flat top (straight_veto)",
        "live": True})
    straight_veto: tuple[float, ...] = field(default=_DEFAULT.straight_veto, metadata={
        "doc": "Calibrated veto between two straight-edged flat tops, per feature",
        "live": True})
    curved_veto: tuple[float, ...] = field(default=_DEFAULT.curved_veto, metadata={
        "doc": "Calibrated veto between two looks of smooth curved tops, per feature",
        "live": True})
    creased_unused: tuple[str, ...] = field(default=CREASED_UNUSED_FEATURES, metadata={
        "doc": "Features left out between two creased looks (names of the mode's features)"})
    min_common_features: int = field(default=6, metadata={
        "doc": "Fewest common known features for a stored look to answer"})
    identify_share: float = field(default=0.5, metadata={
        "doc": "Smallest winner share for a non-final identification", "live": True})
    veto_any_look: bool = field(default=True, metadata={
        "doc": "An address passes the veto when one of its looks does (else its nearest)",
        "live": True})
    crease_found_veto: bool = field(default=True, metadata={
        "doc": "A look that found a crease and no flat top is not an address none of whose "
               "looks found one",
        "live": True})
    rim_found_veto: bool = field(default=True, metadata={
        "doc": "A look that felt a flat top's rim and no crease is not an address all of "
               "whose touched looks found a crease and no rim",
        "live": True})
    veto_rerun: bool = field(default=True, metadata={
        "doc": "After a veto, inhibit the vetoed winner and let the WTA run again, once",
        "live": True})
    refine_looks: int = field(default=12, metadata={
        "doc": "Looks an address may hold at most"})
    learning_rate: float = field(default=0.02, metadata={
        "doc": "Adam step size of the supervised learning module"})
    batch_size: int = field(default=128, metadata={
        "doc": "Samples per replay step"})
    train_steps: int = field(default=40, metadata={
        "doc": "Replay steps always taken after a store"})
    check_every: int = field(default=20, metadata={
        "doc": "Then more steps in blocks of this many until every look is recalled"})
    max_train_steps: int = field(default=400, metadata={
        "doc": "Cap on the replay steps of one store"})
    recall_confidence: float = field(default=0.75, metadata={
        "doc": "Winner share each stored look must reach to end training"})
    new_fraction: float = field(default=0.1, metadata={
        "doc": "Share of the repeats drawn from the object just stored"})
    novel_fraction: float = field(default=0.25, metadata={
        "doc": "Share of each replay batch that is synthetic novel samples"})
    novel_near: float = field(default=1.0, metadata={
        "doc": "Novel samples lie at least this many tau from a stored look"})
    novel_far: float = field(default=3.0, metadata={
        "doc": "Novel samples lie at most this many tau from a stored look"})
    prior_weight: float = field(default=1.0, metadata={
        "doc": "Pull of centres, scales and tau towards stored looks and calibration"})
    unknown_feature_prob: float = field(default=0.5, metadata={
        "doc": "Probability that a replayed maskable feature is made unknown"})
    maskable_features: tuple[str, ...] = field(default=_DEFAULT.maskable_features, metadata={
        "doc": "Features that may be unknown at match time (names of the mode's features)"})
    z_cap: float = field(default=_DEFAULT.z_cap, metadata={
        "doc": "Largest |z| one feature adds to a distance (0: no cap, the paper mode)"})

    def __post_init__(self) -> None:
        try:
            mode = FeatureMode.parse(self.features)
        except (ValueError, TypeError) as exc:
            _fail("features", self.features, str(exc))
        object.__setattr__(self, "features", mode.value)
        object.__setattr__(self, "maskable_features", tuple(self.maskable_features))
        object.__setattr__(self, "creased_unused", tuple(self.creased_unused))
        if mode is FeatureMode.PAPER and self.creased_unused == CREASED_UNUSED_FEATURES:
            # The default names the extended mode's features; the paper mode has no crease.
            object.__setattr__(self, "creased_unused", ())
        self._take_calibration(mode)
        names = feature_names(mode)
        # Per-feature tuples: scales and vetoes positive; weights >= 0, not all 0.
        for name, kind in (("feature_scale", "positive numbers"),
                           ("veto", "positive numbers"), ("flat_veto", "positive numbers"),
                           ("straight_veto", "positive numbers"),
                           ("curved_veto", "positive numbers"),
                           ("feature_weight", "numbers >= 0")):
            value = tuple(float(v) if isinstance(v, (int, float)) and not isinstance(v, bool)
                          else v for v in getattr(self, name))
            object.__setattr__(self, name, value)
            if len(value) != len(names) or not all(
                    isinstance(v, float) and math.isfinite(v)
                    and (v >= 0 if name == "feature_weight" else v > 0) for v in value):
                _fail(name, getattr(self, name),
                      f"{len(names)} {kind}, one per feature of the {mode.value} mode")
        for name in self.maskable_features:
            if name not in names:
                _fail("maskable_features", self.maskable_features, f"names in {names}")
        for name in self.creased_unused:
            if name not in names or "TC" not in names:
                _fail("creased_unused", self.creased_unused,
                      f"names in {names}, in a mode with the crease TC")
        if sum(self.feature_weight) <= 0:
            _fail("feature_weight", self.feature_weight, "not every weight 0")
        _positive("identify_distance", self.identify_distance)
        _positive("noise_dof", self.noise_dof)
        _non_negative("z_cap", self.z_cap)
        _unit("flat_crease", self.flat_crease)
        _unit("flat_curvature", self.flat_curvature)
        _unit("straight_outline", self.straight_outline)
        _positive_int("min_common_features", self.min_common_features)
        if self.min_common_features > len(names):
            _fail("min_common_features", self.min_common_features, f"<= {len(names)}")
        _unit("identify_share", self.identify_share)
        _positive_int("refine_looks", self.refine_looks)
        _positive("learning_rate", self.learning_rate)
        _positive_int("batch_size", self.batch_size)
        _positive_int("train_steps", self.train_steps)
        _positive_int("check_every", self.check_every)
        _positive_int("max_train_steps", self.max_train_steps)
        if self.max_train_steps < self.train_steps:
            _fail("max_train_steps", self.max_train_steps, f">= train_steps={self.train_steps}")
        _unit("recall_confidence", self.recall_confidence)
        _unit("new_fraction", self.new_fraction)
        _unit("novel_fraction", self.novel_fraction)
        if self.novel_fraction >= 1.0:
            _fail("novel_fraction", self.novel_fraction, "< 1")
        _positive("novel_near", self.novel_near)
        _positive("novel_far", self.novel_far)
        if self.novel_far < self.novel_near:
            _fail("novel_far", self.novel_far, f">= novel_near={self.novel_near}")
        _non_negative("prior_weight", self.prior_weight)
        _unit("unknown_feature_prob", self.unknown_feature_prob)

    def _take_calibration(self, mode: FeatureMode) -> None:
        """Each calibrated field left at another mode's calibration takes ``mode``'s."""
        mine = CALIBRATED[mode]
        for f in fields(Calibrated):
            value = _as_tuple(getattr(self, f.name))
            if value == _as_tuple(getattr(mine, f.name)):
                continue
            if any(value == _as_tuple(getattr(other, f.name))
                   for m, other in CALIBRATED.items() if m is not mode):
                object.__setattr__(self, f.name, getattr(mine, f.name))

    @classmethod
    def for_mode(cls, mode: FeatureMode | str, **overrides: Any) -> MemoryConfig:
        """The calibrated defaults of ``mode`` with ``overrides``."""
        return cls(features=FeatureMode.parse(mode).value, **overrides)

    @property
    def feature_mode(self) -> FeatureMode:
        """``features`` as the enum."""
        return FeatureMode(self.features)

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-friendly dict of every field (tuples become lists)."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> MemoryConfig:
        """Inverse of :meth:`to_dict`; unknown keys raise ConfigError.

        Raises:
            ConfigError: A key is not a field or a value is out of range.
        """
        names = {f.name for f in fields(cls)}
        extra = sorted(set(data) - names)
        if extra:
            raise ConfigError(f"MemoryConfig: unknown field(s) {extra}")
        kwargs: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v
                                  for k, v in data.items()}
        return cls(**kwargs)


def _as_tuple(value: Any) -> Any:
    return tuple(value) if isinstance(value, (list, tuple)) else (value,)


def _fail(name: str, value: object, expected: str) -> NoReturn:
    raise ConfigError(f"MemoryConfig.{name}={value!r}: expected {expected}")


def _finite(name: str, value: float) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        _fail(name, value, "a finite number")


def _positive(name: str, value: float) -> None:
    _finite(name, value)
    if value <= 0:
        _fail(name, value, "> 0")


def _non_negative(name: str, value: float) -> None:
    _finite(name, value)
    if value < 0:
        _fail(name, value, ">= 0")


def _unit(name: str, value: float) -> None:
    _finite(name, value)
    if not 0.0 <= value <= 1.0:
        _fail(name, value, "in [0, 1]")


def _positive_int(name: str, value: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        _fail(name, value, "a positive int")


#: The defaults, shared (the dataclass is frozen).
DEFAULT_CONFIG = MemoryConfig()


@dataclass(frozen=True)
class MemoryNodeConfig:
    """What the memory node needs besides MemoryConfig.

    Attributes:
        memory_file: Long-term memory file; loaded at start if it exists, written
            atomically after each store. Empty: memory lives in RAM only.
        seed: Seed of the network's initial weights and training order.
    """

    memory_file: str = ""
    seed: int = 0

    def __post_init__(self) -> None:
        if not isinstance(self.memory_file, str):
            raise ConfigError(f"MemoryNodeConfig.memory_file must be a file name, got "
                              f"{self.memory_file!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ConfigError(f"MemoryNodeConfig.seed must be an integer >= 0, got {self.seed!r}")
