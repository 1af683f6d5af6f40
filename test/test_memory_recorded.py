"""The memory on features recorded from the simulator (test/data/memory_queries.csv.gz).

The file holds every MATCH request the attention loop sent while Roger looked at the six
shipped worlds (both policies, seed 0), made by ``python -m
roger_experiments.record_queries`` (the command is in docs/memory.md). Labels (object,
category) only score; the memory and its calibration never read them.
"""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest
import torch
from conftest import REPO

from roger_common.types import (
    WEIGHT_INDEX,
    FeatureMode,
    MatchOutcome,
    feature_dim,
    feature_names,
)
from roger_experiments.record_queries import Query, ReplayScore, read_csv, replay
from roger_memory.calibration import (
    calibrate,
    choose_z_cap,
    creased_looks,
    curved_looks,
    flat_looks,
    straight_looks,
    two_class_split,
)
from roger_memory.config import (
    CALIBRATED,
    CALIBRATED_FEATURE_SCALE,
    CALIBRATED_FEATURE_WEIGHT,
    CALIBRATED_IDENTIFY_DISTANCE,
    CALIBRATED_NOISE_DOF,
    CALIBRATED_VETO,
    CURVED_VETO_FEATURES,
    FLAT_VETO_FEATURES,
    NEVER_VETO_FEATURES,
    STRAIGHT_VETO_FEATURES,
    MemoryConfig,
)
from roger_memory.memory import AssociativeMemory

DATA = REPO / "test" / "data" / "memory_queries.csv.gz"

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@cache
def _queries(world: str | None = None) -> tuple[Query, ...]:
    rows = read_csv(DATA)
    return tuple(q for q in rows if world is None or q.world == world)


@cache
def _replayed(world: str) -> tuple[list[ReplayScore], tuple[AssociativeMemory, ...]]:
    memories: list[AssociativeMemory] = []

    def make() -> AssociativeMemory:
        memories.append(AssociativeMemory(MemoryConfig.for_mode("paper"), seed=0))
        return memories[-1]

    return replay(_queries(world), make), tuple(memories)


def test_the_recorded_file_covers_the_shipped_worlds() -> None:
    rows = _queries()
    assert {q.world for q in rows} == {"inspection", "categories", "two_rows", "shapes",
                                       "table1", "twins"}
    assert {q.action for q in rows} == {"shift", "visual", "haptic"}
    assert len(rows) > 1500
    assert 0.3 < np.mean([q.known[WEIGHT_INDEX] for q in rows]) < 0.95


def test_the_shipped_calibration_is_what_the_recorded_looks_give() -> None:
    """The defaults are measured, not set: calibrate() on the robot's own looks (labels
    unused) gives them back."""
    rows = _queries()
    cal = calibrate(np.stack([q.features for q in rows]), np.stack([q.known for q in rows]),
                    np.array([f"{q.world}/{q.policy}/{q.seed}" for q in rows]),
                    np.array([q.entry for q in rows]))
    np.testing.assert_allclose(cal.feature_scale, CALIBRATED_FEATURE_SCALE, rtol=0.01, atol=5e-5)
    assert cal.identify_distance == pytest.approx(CALIBRATED_IDENTIFY_DISTANCE, abs=0.01)
    assert cal.noise_dof == pytest.approx(CALIBRATED_NOISE_DOF, abs=0.1)
    np.testing.assert_allclose(cal.veto, CALIBRATED_VETO, rtol=0.01, atol=5e-4)
    np.testing.assert_allclose(cal.feature_weight, CALIBRATED_FEATURE_WEIGHT, rtol=0.01,
                               atol=2e-3)
    # The category-level spread is wider than one object's look-to-look scatter: the
    # intensity of a copy seen at another place varies 2-6 times more.
    assert np.all(cal.feature_scale >= cal.entry_scale)
    assert cal.feature_scale[2] > 5 * cal.entry_scale[2]


def test_the_shipped_extended_calibration_is_what_the_recorded_extended_looks_give() -> None:
    """The extended mode's defaults are measured the same way, on its own recorded looks
    (test/data/memory_queries_extended.csv.gz: no inspection look in it), its cap of
    one feature's |z| included (``choose_z_cap``)."""
    rows = read_csv(REPO / "test" / "data" / "memory_queries_extended.csv.gz")
    assert "inspection" not in {q.world for q in rows}
    assert all(len(q.features) == feature_dim("extended") for q in rows)
    names = feature_names("extended")
    x, known = np.stack([q.features for q in rows]), np.stack([q.known for q in rows])
    defaults = MemoryConfig.for_mode("extended")
    ext = CALIBRATED[FeatureMode.EXTENDED]
    ext_unused = defaults.creased_unused
    assert ext_unused == ("O", "A", "I1", "I2", "I3", "T1", "T2", "T3")
    flat = flat_looks(x, known, names.index("TC"), names.index("TK"), defaults.flat_crease,
                      defaults.flat_curvature)
    o = names.index("O")
    # The outline of a straight-edged top: the two-class split of the flat looks' O.
    split = two_class_split(x[flat & known[:, o], o])
    assert split == pytest.approx(ext.straight_outline, abs=5e-4)
    straight = straight_looks(x, known, flat, o, split)
    assert 0.3 < straight.sum() / flat.sum() < 0.7  # boxes against cylinders
    curved = curved_looks(x, known, names.index("TC"), names.index("TK"),
                          defaults.flat_crease, defaults.flat_curvature)
    assert 0.05 < curved.mean() < 0.4  # spheres
    cal, scores = choose_z_cap(x, known,
                               np.array([f"{q.world}/{q.policy}/{q.seed}" for q in rows]),
                               np.array([q.entry for q in rows]),
                               vetoing=np.array([n not in NEVER_VETO_FEATURES
                                                 for n in names]),
                               flat=flat,
                               flat_vetoing=np.array([n in FLAT_VETO_FEATURES for n in names]),
                               creased=creased_looks(x, known, names.index("TC"),
                                                     defaults.flat_crease),
                               creased_unused=np.array([n in ext_unused for n in names]),
                               straight=straight,
                               straight_vetoing=np.array([n in STRAIGHT_VETO_FEATURES
                                                          for n in names]),
                               curved=curved,
                               curved_vetoing=np.array([n in CURVED_VETO_FEATURES
                                                        for n in names]))
    # A third of the looks are of tops the hand found smooth and flat (boxes, cylinders).
    assert 0.2 < flat.mean() < 0.6
    assert cal.flat_veto is not None
    np.testing.assert_allclose(cal.flat_veto, ext.flat_veto, rtol=0.01, atol=5e-4)
    assert cal.straight_veto is not None
    np.testing.assert_allclose(cal.straight_veto, ext.straight_veto, rtol=0.01, atol=5e-4)
    # Between straight-edged tops A vetoes closer than between flat tops at large.
    a = names.index("A")
    assert cal.straight_veto[a] < 0.5 * cal.flat_veto[a]
    # Between two spheres AS vetoes within a Table-1 step of grey (15/255 of albedo).
    assert cal.curved_veto is not None
    np.testing.assert_allclose(cal.curved_veto, ext.curved_veto, rtol=0.01, atol=5e-4)
    assert cal.curved_veto[names.index("AS")] < 15.0 / 255.0
    assert min(scores, key=lambda cap: scores[cap]) == ext.z_cap
    # The cap matters: none, or the old 3, lets the acceptance take in more other looks.
    assert scores[0.0] > scores[3.0] > scores[ext.z_cap]
    assert cal.between_accepted == pytest.approx(scores[ext.z_cap])
    np.testing.assert_allclose(cal.feature_scale, ext.feature_scale, rtol=0.01, atol=5e-5)
    assert cal.identify_distance == pytest.approx(ext.identify_distance, abs=0.01)
    assert cal.noise_dof == pytest.approx(ext.noise_dof, abs=0.1)
    np.testing.assert_allclose(cal.veto, ext.veto, rtol=0.01, atol=5e-4)
    np.testing.assert_allclose(cal.feature_weight, ext.feature_weight, rtol=0.01, atol=2e-3)
    # The paper's eleven keep their place and the config of each mode takes its own.
    assert MemoryConfig.for_mode("extended").feature_scale == ext.feature_scale
    assert MemoryConfig.for_mode("paper").feature_scale == CALIBRATED_FEATURE_SCALE


def test_information_weights_follow_what_a_feature_tells_apart() -> None:
    """A feature that varies between entries no more than between two looks of one
    category tells nothing and weighs ~0; the one that parts categories most weighs most.
    Synthetic looks: 12 categories, 3 entries (copies) each, 4 looks per entry."""
    rng = np.random.default_rng(5)
    n_cat, copies, looks = 12, 3, 4
    centre = rng.random((n_cat, 11)) * np.linspace(1.0, 0.1, 11)  # feature 0 parts most
    centre[:, 1] = 0.5                                              # feature 1: nothing
    x, entry = [], []
    for c in range(n_cat):
        for e in range(copies):
            copy = centre[c] + rng.normal(0.0, 0.01, 11)
            for _ in range(looks):
                x.append(copy + rng.normal(0.0, 0.005, 11))
                entry.append(c * copies + e)
    x = np.clip(np.array(x), 0.0, 1.0)
    cal = calibrate(x, np.ones_like(x, bool), np.zeros(len(x)), np.array(entry))
    assert cal.feature_weight.mean() == pytest.approx(1.0)
    assert cal.feature_weight[1] < 0.15 * cal.feature_weight[0]
    assert int(np.argmax(cal.feature_weight)) == 0


def test_the_cap_is_chosen_where_outliers_would_widen_tau_and_not_where_there_are_none(
        ) -> None:
    """``choose_z_cap`` on synthetic looks (12 categories, 3 copies, 4 looks each): where
    a few features jump between looks of one object now and then (a prism's outline at
    another yaw), no cap lets those jumps set a wide tau that takes in other categories,
    and a finite cap wins; with Gaussian looks only, a cap buys nothing."""
    def looks(jumps: bool) -> tuple[np.ndarray, np.ndarray]:
        rng = np.random.default_rng(7)
        centre = 0.5 + rng.normal(0.0, 0.04, (12, 11))  # categories a few scales apart
        x, entry = [], []
        for c in range(12):
            for e in range(3):
                copy = centre[c] + rng.normal(0.0, 0.02, 11)
                for _ in range(4):
                    look = copy + rng.normal(0.0, 0.01, 11)
                    for f in range(3 if jumps else 0):  # 5 % of looks jump in I1-I3
                        if rng.random() < 0.05:
                            look[f] += rng.choice([-1.0, 1.0]) * 0.3
                    x.append(look)
                    entry.append(c * 3 + e)
        return np.clip(np.array(x), 0.0, 1.0), np.array(entry)

    x, entry = looks(jumps=True)
    cal, scores = choose_z_cap(x, np.ones_like(x, bool), np.zeros(len(x)), entry)
    best = min(scores, key=lambda cap: scores[cap])
    assert best > 0 and scores[0.0] > 2 * scores[best], scores
    assert cal.between_accepted == pytest.approx(scores[best])
    uncapped = calibrate(x, np.ones_like(x, bool), np.zeros(len(x)), entry)
    assert cal.identify_distance < uncapped.identify_distance
    x, entry = looks(jumps=False)
    _, scores = choose_z_cap(x, np.ones_like(x, bool), np.zeros(len(x)), entry)
    assert scores[0.0] <= min(scores.values()) + 0.03, scores  # within its noise


def test_the_network_itself_turns_down_what_the_veto_did() -> None:
    """With every feature weighted alike, two_rows' replay needs the distance veto 7 times
    (19 with the calibration of before the weights): the weak features, S and T, dilute
    a clear difference in I or W below the acceptance distance. Weighted by what each
    feature tells, the network's own decision says new there, and the veto (kept as a
    safety net) has little left to do."""
    _, memories = _replayed("two_rows")
    assert sum(m.stats.vetoes for m in memories) <= 2


def test_an_untrained_network_of_the_same_shape_changes_most_decisions() -> None:
    """Ablation: the memory of a replayed run, asked every recorded query of that world
    with its trained network and with an untrained one of the same shape (same units and
    outputs, weights never trained): most (outcome, address) pairs change."""
    _, memories = _replayed("inspection")
    memory = memories[0]
    untrained = memory.network.untrained_copy(torch.Generator().manual_seed(0))
    changed = 0
    queries = _queries("inspection")
    for q in queries:
        a = memory.decide(q.features, q.known, q.final, network=memory.network).result
        b = memory.decide(q.features, q.known, q.final, network=untrained).result
        changed += (a.outcome, a.address) != (b.outcome, b.address)
    assert changed > 0.6 * len(queries), (changed, len(queries))


@pytest.mark.parametrize("world", ["two_rows", "twins", "categories", "inspection"])
def test_recorded_foci_are_identified_as_their_own_category(world: str) -> None:
    """Replayed as the straightforward policy takes them, the recorded foci of each run
    are identified as the category stored from them, at the issue's identification
    precision (0.95) or better: on inspection 1 of 41 is another category (straightforward
    run), 0 of 38 (Q-learning). Measured exception: in categories.yaml a prism on the
    1.0 m ring is out of the arms' reach, so its final trial has no weight and decides on
    vision, which takes it for the cylinder or the sphere (4 slips in the Q-learning
    run)."""
    scores, _ = _replayed(world)
    wrong = sum(s.identifications - s.correct_identifications for s in scores)
    if world == "categories":
        assert wrong <= 4
    else:
        assert all(s.correct_identifications >= 0.95 * s.identifications for s in scores)
    assert all(s.identifications > 10 for s in scores)


def test_weight_twins_are_stored_once_each_and_never_confused() -> None:
    """worlds/twins.yaml: a light and a heavy box (and can) that look the same. Each of
    the four categories is stored once, and no look is identified as its twin."""
    scores, memories = _replayed("twins")
    for s in scores:
        assert s.stores == s.correct_stores == s.categories == 4
        assert s.correct_identifications == s.identifications
        assert s.false_identified == 0
    for memory in memories:
        weights = sorted(float(memory.exemplars(a)[0, WEIGHT_INDEX]) for a in range(4))
        # 0.15, 0.25, 0.45, 0.55: all four weights, each within 0.04 (under half the 0.1
        # between neighbours) of a different one
        assert np.abs(np.array(weights) - [0.15, 0.25, 0.45, 0.55]).max() < 0.04, weights
        assert memory.stats.coverage_holds > 0  # vision alone was never enough


def test_no_look_without_weight_is_identified_before_the_final_trial() -> None:
    """The rule of item 4 on real looks: a non-final look that does not know W is never
    identified as an address that knows it."""
    _, memories = _replayed("twins")
    memory = memories[0]
    for q in _queries("twins"):
        if q.final or q.known[WEIGHT_INDEX]:
            continue
        assert memory.decide(q.features, q.known, False,
                             network=memory.network).result.outcome != MatchOutcome.IDENTIFIED


def test_the_two_class_split_falls_in_the_gap_between_two_groups() -> None:
    """``two_class_split`` (the straight-edged tops' outline, MemoryConfig.straight_outline)
    lies between two groups of values (cylinders' outlines about 0.05, boxes' about 0.16,
    each object's looks spread by its own noise) in either proportion, and between two
    distinct values; it needs two."""
    rng = np.random.default_rng(5)
    for n_low, n_high in ((300, 300), (100, 500), (500, 100)):
        low = np.clip(rng.normal(0.05, 0.01, n_low), 0.0, None)
        high = rng.normal(0.16, 0.012, n_high)
        split = two_class_split(np.concatenate([high, low]))
        assert low.max() < split < high.min(), (n_low, n_high)
    assert two_class_split(np.array([0.2, 0.2, 0.4])) == pytest.approx(0.3)
    with pytest.raises(ValueError, match="two distinct"):
        two_class_split(np.array([0.1, 0.1]))


def test_a_measurement_shared_by_the_looks_of_one_entry_cannot_set_a_veto_under_its_noise(
        ) -> None:
    """Every look of an object carries its last weighing, so two looks of one map entry
    often show the same W: their differences understate the noise of two weighings. The
    veto is floored at the ``veto_quantile`` of two looks' difference under the category
    scale, so copies weighed apart by their own noise are not turned down. Synthetic
    looks (12 categories, 3 copies, 6 looks each): feature 10 is weighed anew every
    second look, and each weighing is shared by two looks (without the floor the
    assertions fail: the vetoes then lie at 0.8-0.9 of it)."""
    from statistics import NormalDist

    rng = np.random.default_rng(11)
    centre = rng.random((12, 11))
    x, entry = [], []
    for c in range(12):
        for e in range(3):
            weighings = centre[c, 10] + rng.normal(0.0, 0.01, 3)
            for k in range(6):
                look = centre[c] + rng.normal(0.0, 0.01, 11)
                look[10] = weighings[k // 2]
                x.append(look)
                entry.append(c * 3 + e)
    x = np.clip(np.array(x), 0.0, 1.0)
    cal = calibrate(x, np.ones_like(x, bool), np.zeros(len(x)), np.array(entry))
    floor = NormalDist().inv_cdf(0.5 + 0.999 / 2.0) * np.sqrt(2.0) * cal.feature_scale
    assert np.all(cal.veto >= floor - 1e-12)
    # The floor acts: 36 entries' repeats hold too few independent differences for their
    # 99.9th percentile to reach the Gaussian's (0.8-0.9 of it on most features here).
    assert np.sum(np.isclose(cal.veto, floor)) >= 5
