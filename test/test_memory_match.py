"""Match and store in the associative memory: the three outcomes of section 4.2.

Synthetic objects with the robot's own noise: each query is a stored look moved by the
calibrated repeat noise (per feature sqrt(2) sigma_f times a Student-t, MemoryConfig's
feature_scale and noise_dof), not by a hand-picked Gaussian. Tests on features recorded
from the simulator are in test_memory_recorded.py.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from roger_common.errors import MessageError
from roger_common.types import (
    FEATURE_DIM,
    FEATURE_NAMES,
    WEIGHT_INDEX,
    MatchOutcome,
    MatchResult,
    MemoryOp,
    MemoryRequest,
    feature_names,
)
from roger_memory.config import MemoryConfig
from roger_memory.memory import AssociativeMemory, Decision
from roger_memory.network import student_t_noise

ALL_KNOWN = np.ones(FEATURE_DIM, bool)
W_UNKNOWN = ALL_KNOWN.copy()
W_UNKNOWN[WEIGHT_INDEX] = False
CONFIG = MemoryConfig.for_mode("paper")  # these tests build paper-mode (11) looks
SIGMA = np.sqrt(2.0) * np.asarray(CONFIG.feature_scale)


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _distinct_patterns(n: int, seed: int) -> np.ndarray:
    x = np.random.default_rng(seed).uniform(0.1, 0.9, (n, FEATURE_DIM)).astype(np.float32)
    z = np.abs(x[:, None] - x[None]) / SIGMA
    rms = np.sqrt((z ** 2).mean(axis=2))
    assert n == 1 or rms[~np.eye(n, dtype=bool)].min() > 3 * CONFIG.identify_distance
    return x


def _look(x: np.ndarray, rng: np.random.Generator, scale: float = 1.0) -> np.ndarray:
    """Another look at the object of ``x``: the calibrated repeat noise."""
    noise = student_t_noise(rng, (1, FEATURE_DIM), CONFIG.noise_dof)[0] * SIGMA * scale
    return np.clip(x + noise, 0.0, 1.0).astype(np.float32)


def _moved(x: np.ndarray, distance: float, rng: np.random.Generator,
           known: np.ndarray = ALL_KNOWN) -> np.ndarray:
    """``x`` moved by a (weighted, as the memory measures it) RMS z-distance ``distance``
    in a random direction."""
    w = np.asarray(CONFIG.feature_weight)
    d = rng.standard_normal(FEATURE_DIM) * known
    d /= np.sqrt((w * d ** 2).sum() / (w * known).sum())
    return (x + d * distance * SIGMA).astype(np.float32)


@pytest.fixture(scope="module")
def ten() -> tuple[AssociativeMemory, np.ndarray]:
    patterns = _distinct_patterns(10, seed=11)
    memory = AssociativeMemory(CONFIG, seed=0)
    addresses = [memory.store(p, ALL_KNOWN) for p in patterns]
    assert addresses == list(range(10))
    return memory, patterns


def test_repeat_looks_are_identified_at_the_calibrated_rate(ten) -> None:
    """tau is the 95th percentile of the robot's own repeat looks: about 95 % of repeat
    looks are taken for their object, and never for another one."""
    memory, patterns = ten
    rng = np.random.default_rng(1)
    outcomes = []
    for _ in range(20):
        for address, p in enumerate(patterns):
            result = memory.match(_look(p, rng), ALL_KNOWN)
            assert result.address == address
            outcomes.append(result.outcome)
    identified = outcomes.count(MatchOutcome.IDENTIFIED) / len(outcomes)
    assert 0.88 <= identified <= 1.0, identified
    assert set(outcomes) <= {MatchOutcome.IDENTIFIED, MatchOutcome.UNDETERMINED}


def test_the_novel_unit_wins_beyond_the_acceptance_distance(ten) -> None:
    memory, patterns = ten
    rng = np.random.default_rng(2)
    for p in patterns:
        near = memory.decide(_moved(p, 0.5 * CONFIG.identify_distance, rng), ALL_KNOWN, True)
        far = memory.decide(_moved(p, 2.0 * CONFIG.identify_distance, rng), ALL_KNOWN, True)
        assert near.result.outcome == MatchOutcome.IDENTIFIED
        assert (far.winner, far.result.outcome) == (-1, MatchOutcome.NEW)
        assert memory.match(_moved(p, 2.0 * CONFIG.identify_distance, rng),
                            ALL_KNOWN).outcome == MatchOutcome.UNDETERMINED
    assert memory.size == 10  # a NEW outcome does not store by itself


def test_a_final_trial_that_sees_enough_is_never_undetermined(ten) -> None:
    memory, patterns = ten
    rng = np.random.default_rng(5)
    queries = [_look(p, rng, 3.0) for p in patterns] + list(rng.random((10, FEATURE_DIM)))
    for q in queries:
        for known in (ALL_KNOWN, W_UNKNOWN):
            result = memory.match(q, known, final_trial=True)
            assert result.outcome != MatchOutcome.UNDETERMINED
            assert (result.address >= 0) == (result.outcome == MatchOutcome.IDENTIFIED)


def test_a_final_look_that_knows_too_few_features_is_undetermined_and_stores_nothing(
        ten) -> None:
    # An object hidden behind another: perception gives no I, T, S, D; touch gives W.
    memory, patterns = ten
    only_w = np.zeros(FEATURE_DIM, bool)
    only_w[WEIGHT_INDEX] = True
    few = ALL_KNOWN.copy()
    few[CONFIG.min_common_features - 1:] = False  # one fewer than any unit compares
    size, revision, matches = memory.size, memory.revision, memory.stats.matches
    for known in (only_w, few):
        result = memory.match(1.0 - patterns[0], known, final_trial=True)
        assert (result.outcome, result.address) == (MatchOutcome.UNDETERMINED, -1)
    assert (memory.stats.unseen, memory.stats.matches) == (2, matches + 2)
    assert (memory.size, memory.revision) == (size, revision)
    enough = few.copy()
    enough[CONFIG.min_common_features - 1] = True
    assert memory.match(1.0 - patterns[0], enough, final_trial=True).outcome \
        is not MatchOutcome.UNDETERMINED
    empty = AssociativeMemory(CONFIG)
    assert empty.match(patterns[0], only_w, final_trial=True).outcome \
        is MatchOutcome.UNDETERMINED
    assert empty.match(patterns[0], ALL_KNOWN, final_trial=True).outcome is MatchOutcome.NEW


def test_a_match_that_identifies_nothing_changes_nothing(ten) -> None:
    memory, patterns = ten
    state = {k: v.clone() for k, v in memory.network.state_dict().items()}
    revision = memory.revision
    memory.match(1.0 - patterns[0], ALL_KNOWN)
    memory.match(1.0 - patterns[1], ALL_KNOWN, final_trial=True)
    for name, value in memory.network.state_dict().items():
        assert torch.equal(value, state[name]), name
    assert memory.revision == revision


def test_weight_twins_are_told_apart_only_after_the_weight_is_measured() -> None:
    """Two objects that differ only in W: without W no non-final identification (vision
    cannot exclude the twin); with W each is identified as itself; the final trial
    decides on what is known: without W it takes a look for one of the twins (the looks
    carry the calibrated repeat noise, of which the acceptance distance keeps 95 %: a
    few may come out new, none as the third object)."""
    x = _distinct_patterns(3, seed=12)
    x[2] = x[1]
    x[1, WEIGHT_INDEX], x[2, WEIGHT_INDEX] = 0.15, 0.45
    memory = AssociativeMemory(CONFIG, seed=1)
    for p in x:
        memory.store(p, ALL_KNOWN)
    rng = np.random.default_rng(3)
    twin = 0
    for which in (1, 2):
        for _ in range(10):
            q = _look(x[which], rng)
            before = memory.match(np.where(W_UNKNOWN, q, 0.0), W_UNKNOWN)
            assert before.outcome == MatchOutcome.UNDETERMINED
            after = memory.match(q, ALL_KNOWN)
            assert after.outcome != MatchOutcome.IDENTIFIED or after.address == which
            final = memory.match(q, ALL_KNOWN, final_trial=True)
            assert final.outcome == MatchOutcome.NEW or final.address == which
            final_w = memory.match(q, W_UNKNOWN, final_trial=True)
            assert final_w.outcome == MatchOutcome.NEW or final_w.address in (1, 2)
            twin += final_w.outcome == MatchOutcome.IDENTIFIED
    assert twin >= 17


def test_a_heavy_twin_of_a_stored_light_object_is_new() -> None:
    light = _distinct_patterns(1, seed=13)[0]
    light[WEIGHT_INDEX] = 0.15
    memory = AssociativeMemory(CONFIG, seed=2)
    memory.store(light, ALL_KNOWN)
    heavy = light.copy()
    heavy[WEIGHT_INDEX] = 0.55
    rng = np.random.default_rng(4)
    for _ in range(10):
        q = _look(heavy, rng)
        assert memory.match(np.where(W_UNKNOWN, q, 0), W_UNKNOWN).outcome == \
            MatchOutcome.UNDETERMINED
        assert memory.match(q, ALL_KNOWN, final_trial=True).outcome == MatchOutcome.NEW


def test_unknown_weight_is_not_taken_as_zero() -> None:
    x = _distinct_patterns(2, seed=14)
    x[:, WEIGHT_INDEX] = 0.6
    memory = AssociativeMemory(CONFIG, seed=2)
    for p in x:
        memory.store(p, W_UNKNOWN)  # stored without a weight (the arm never reached it)
    q = x[0].copy()
    q[WEIGHT_INDEX] = 0.0
    # Unknown W is left out, not read as 0: on sight the look is object 0. Before a
    # haptic improvement touch could still tell, so only the final trial identifies.
    first = memory.match(q, W_UNKNOWN)
    assert (first.outcome, first.address) == (MatchOutcome.UNDETERMINED, 0)
    final = memory.match(q, W_UNKNOWN, final_trial=True)
    assert (final.outcome, final.address) == (MatchOutcome.IDENTIFIED, 0)


def test_an_object_never_weighed_does_not_take_in_a_weighed_look() -> None:
    # An address stored without W (out of the arms' reach) agrees on sight with objects of
    # every weight; a look whose weight is measured is therefore never identified as it
    # (on random worlds with objects out of reach it took in most of the reachable
    # categories: docs/memory.md). Addresses that were weighed still identify it.
    x = _distinct_patterns(2, seed=14)
    x[:, WEIGHT_INDEX] = 0.6
    memory = AssociativeMemory(CONFIG, seed=2)
    memory.store(x[0], W_UNKNOWN)
    memory.store(x[1], ALL_KNOWN)
    assert memory.match(x[0], ALL_KNOWN, final_trial=True).outcome == MatchOutcome.NEW
    assert memory.match(x[1], ALL_KNOWN, final_trial=True).address == 1
    # Without W the look is still the unweighed object on sight (final trial).
    assert memory.match(x[0], W_UNKNOWN, final_trial=True).address == 0


def test_the_veto_turns_down_a_single_feature_beyond_any_repeat() -> None:
    """A query equal to a stored look but for W, off by more than the veto yet within
    the acceptance distance overall: the network would identify, the veto does not."""
    x = _distinct_patterns(1, seed=15)[0]
    memory = AssociativeMemory(CONFIG, seed=3)
    memory.store(x, ALL_KNOWN)
    q = x.copy()
    q[WEIGHT_INDEX] += 1.1 * CONFIG.veto[WEIGHT_INDEX]
    decision = memory.decide(q, ALL_KNOWN, final_trial=True)
    assert decision.winner == 0 and decision.vetoed
    assert decision.distance < CONFIG.identify_distance
    assert decision.result.outcome == MatchOutcome.NEW
    assert memory.match(q, ALL_KNOWN).outcome == MatchOutcome.UNDETERMINED
    assert memory.stats.vetoes == 2


def _tight_i1(**overrides: object) -> tuple[MemoryConfig, np.ndarray]:
    """The paper calibration with I1's veto two of its category scales (the others as
    calibrated: several scales), and those scales."""
    scale = np.asarray(CONFIG.feature_scale)
    veto = list(CONFIG.veto)
    veto[0] = 2.0 * float(scale[0])
    return MemoryConfig.for_mode("paper", veto=tuple(veto), **overrides), scale


def test_an_address_passes_the_veto_when_any_of_its_looks_does() -> None:
    """An address holds two looks of one object. Its nearest look to the query differs in
    I1 by more than I1's veto; the other is farther overall (in the textures) but within
    every veto. The object was seen that way, so the veto lets the address pass; judged
    by its nearest look alone, the look is stored as new."""
    for any_look, outcome in ((True, MatchOutcome.IDENTIFIED), (False, MatchOutcome.NEW)):
        cfg, scale = _tight_i1(veto_any_look=any_look, veto_rerun=False)
        x = _distinct_patterns(1, seed=21)[0]
        near, far = x.copy(), x.copy()
        near[0] += 2.5 * scale[0]  # beyond I1's veto (2 scales), nothing else off
        far[0] += 1.0 * scale[0]
        far[3:6] += 3.0 * scale[3:6]  # T1-3: farther, within their vetoes
        memory = AssociativeMemory(cfg, seed=3)
        memory.decide(near, ALL_KNOWN, focus_id=1)
        memory.decide(far, ALL_KNOWN, focus_id=1)
        assert memory.store(far, ALL_KNOWN, focus_id=1) == 0
        assert len(memory.exemplars(0)) == 2
        decision = memory.decide(x, ALL_KNOWN, final_trial=True)
        assert decision.winner == 0
        assert decision.result.outcome == outcome, any_look
        assert decision.vetoed is (not any_look)


def test_a_look_that_never_measured_the_vetoing_feature_cannot_let_its_address_pass(
) -> None:
    """An address holds a look that measured I1 and one that did not (its store's final
    look). A query equal to the second but for I1, beyond I1's veto from the first: the
    second is nearest and cannot compare I1, so judged by the nearest look alone the
    query is identified; a look may let the address pass only if it compares every
    feature some look of the address compares, so the first one's I1 vetoes."""
    for any_look, outcome in ((True, MatchOutcome.NEW), (False, MatchOutcome.IDENTIFIED)):
        cfg, scale = _tight_i1(veto_any_look=any_look, veto_rerun=False)
        x = _distinct_patterns(1, seed=24)[0]
        measured = x.copy()
        measured[3:6] += 1.0 * scale[3:6]
        no_i1 = ALL_KNOWN.copy()
        no_i1[0] = False
        memory = AssociativeMemory(cfg, seed=3)
        memory.decide(measured, ALL_KNOWN, focus_id=1)
        assert memory.store(np.where(no_i1, x, 0.0), no_i1, focus_id=1) == 0
        assert memory.exemplar_known(0)[:, 0].tolist() == [True, False]
        q = x.copy()
        q[0] += 2.5 * scale[0]  # beyond I1's veto (2 scales) from the look that has I1
        decision = memory.decide(q, ALL_KNOWN, final_trial=True)
        assert decision.winner == 0
        assert decision.result.outcome == outcome, any_look
        assert decision.vetoed is any_look


def test_after_a_veto_the_winner_take_all_runs_again_without_the_vetoed_unit() -> None:
    """Two addresses: A, the network's winner, differs from the query in I1 beyond its
    veto; B, nearly as near, is within every veto. Inhibiting A, the WTA runs again and B
    wins over the novel unit; without the rerun the look is new. Where the next unit is
    the novel one (B far), the look stays new."""
    cfg, scale = _tight_i1(veto_rerun=True)
    x = _distinct_patterns(1, seed=22)[0]
    q = x.copy()
    q[0] += 2.5 * scale[0]
    b = q.copy()
    b[3:6] += 3.0 * scale[3:6]
    for rerun in (True, False):
        memory = AssociativeMemory(dataclasses.replace(cfg, veto_rerun=rerun), seed=3)
        memory.store(x, ALL_KNOWN)
        memory.store(b, ALL_KNOWN)
        decision = memory.decide(q, ALL_KNOWN, final_trial=True)
        if rerun:
            assert decision.result == MatchResult(MatchOutcome.IDENTIFIED, 1,
                                                  decision.share)
            assert not decision.vetoed and 0.0 < decision.share <= 1.0
        else:
            assert decision.winner == 0 and decision.vetoed
            assert decision.result.outcome == MatchOutcome.NEW
        assert memory.stats.vetoes == 1
    far = _distinct_patterns(2, seed=23)[1]
    memory = AssociativeMemory(cfg, seed=3)
    memory.store(x, ALL_KNOWN)
    memory.store(far, ALL_KNOWN)
    decision = memory.decide(q, ALL_KNOWN, final_trial=True)
    assert decision.winner == 0 and decision.vetoed
    assert decision.result.outcome == MatchOutcome.NEW


def test_in_the_extended_mode_only_view_invariant_features_veto() -> None:
    """A copy seen from another place differs in I, T, S or O by more than one object's
    own looks do: in the extended mode those features count in the distance but never
    veto. A difference in W (or D, H, TH) beyond its veto still turns the look down."""
    from roger_memory.calibration import NO_VETO
    from roger_memory.config import NEVER_VETO_FEATURES

    cfg = MemoryConfig.for_mode("extended")
    names = feature_names("extended")
    known = np.ones(len(names), bool)
    x = np.full(len(names), 0.4)
    assert {n for n, v in zip(names, cfg.veto, strict=True) if v >= NO_VETO} == {
        *NEVER_VETO_FEATURES}
    # Each offset lies beyond the feature's old (one-look) veto: I1 0.148, S3 0.212,
    # O 0.564; W's and D's beyond their veto now (0.049, 0.0375). Alone each stays within
    # the acceptance distance.
    # TC (a crease the probes can miss) never vetoes by its difference either: a query
    # that missed the address's crease passes (one found against none is another rule,
    # test_a_crease_found_is_not_an_address_that_never_found_one); TK, measured on smooth
    # surfaces, does, and so does AP, a prism's albedo from the faces the hand touched.
    for name, offset, vetoed in (("I1", 0.2, False), ("S3", 0.3, False), ("O", 0.6, False),
                                 ("TC", -0.35, False), ("W", 0.053, True), ("D", 0.042, True),
                                 ("TK", 0.4, True), ("AP", 0.045, True)):
        memory = AssociativeMemory(cfg, seed=3)
        memory.store(x, known)
        q = x.copy()
        q[names.index(name)] += offset
        decision = memory.decide(q, known, final_trial=True)
        assert decision.distance < cfg.identify_distance, name
        assert decision.vetoed is vetoed, name
        assert decision.result.outcome == (MatchOutcome.NEW if vetoed
                                           else MatchOutcome.IDENTIFIED), name


def test_the_outline_vetoes_only_between_tops_the_hand_found_smooth_and_flat() -> None:
    """A box and a cylinder of one size, grey and weight differ in the fovea's outline O
    alone, which the cap keeps within the acceptance distance; between two looks whose
    touches found a smooth flat top (TC and TK low) O vetoes at ``flat_veto``. A prism's
    outline (TC high: it turns with the yaw) and a sphere's (TK high) do not veto."""
    cfg = MemoryConfig.for_mode("extended")
    names = feature_names("extended")
    o, tc, tk = names.index("O"), names.index("TC"), names.index("TK")
    assert cfg.flat_veto[o] < 0.13 and cfg.veto[o] >= 1.0
    assert all(v >= 1.0 for i, v in enumerate(cfg.flat_veto)
               if names[i] not in ("O", "A", "TR"))
    assert cfg.flat_veto[names.index("A")] < 1.0  # a flat top's grey: the same everywhere
    known = np.ones(len(names), bool)
    for what, crease, curvature, vetoed in (("box against cylinder", 0.1, 0.0, True),
                                            ("prism at another yaw", 1.0, 0.0, False),
                                            ("sphere", 0.1, 0.5, False)):
        x = np.full(len(names), 0.4)
        x[tc], x[tk], x[o] = crease, curvature, 0.05
        memory = AssociativeMemory(cfg, seed=3)
        memory.store(x, known)
        q = x.copy()
        q[o] = 0.18  # a box's outline against a cylinder's
        decision = memory.decide(q, known, final_trial=True)
        assert decision.distance < cfg.identify_distance, what
        assert decision.vetoed is vetoed, what
        # A look without touch is not known to be flat: O does not veto.
        unknown = known.copy()
        unknown[[tc, tk]] = False
        assert memory.decide(q, unknown, final_trial=True).vetoed is False, what
    # In the paper mode the rule has nothing to read (no touch features).
    paper = MemoryConfig.for_mode("paper")
    assert all(v >= 1.0 for v in paper.flat_veto)


def test_the_rims_curvature_vetoes_only_between_flat_tops() -> None:
    """TR (the curvature of a flat top's rim under the tactile array: a box's edge about 0,
    a 10 cm cylinder's about 0.4) vetoes between two looks the hand found smooth and flat,
    at ``flat_veto``; never in general (two looks of one object share one value, so its own
    repeats measure no noise), and not where either look has not felt a rim."""
    cfg = MemoryConfig.for_mode("extended")
    names = feature_names("extended")
    r, o, tc, tk = (names.index(n) for n in ("TR", "O", "TC", "TK"))
    assert cfg.veto[r] >= 1.0 and 0.1 < cfg.flat_veto[r] < 0.4
    known = np.ones(len(names), bool)
    x = np.full(len(names), 0.4)
    x[tc], x[tk], x[o], x[r] = 0.1, 0.0, 0.12, 0.02  # a box, its outline near the split
    for what, crease, curvature, vetoed in (("flat tops", 0.1, 0.0, True),
                                            ("touch found a crease", 1.0, 0.0, False)):
        stored = x.copy()
        stored[tc], stored[tk] = crease, curvature
        memory = AssociativeMemory(cfg, seed=3)
        memory.store(stored, known)
        q = stored.copy()
        q[r] = 0.45  # a cylinder's rim
        decision = memory.decide(q, known, final_trial=True)
        assert decision.vetoed is vetoed, what
        unknown = known.copy()
        unknown[r] = False
        assert memory.decide(q, unknown, final_trial=True).vetoed is False, what
    # Within the flat veto: two boxes' rims, or a big cylinder's against another's.
    memory = AssociativeMemory(cfg, seed=3)
    memory.store(x, known)
    q = x.copy()
    q[r] = 0.12
    assert memory.decide(q, known, final_trial=True).vetoed is False


def _touched_decision(stored: list[tuple[float, bool]], query_tc: float,
                      config: MemoryConfig | None = None, rim: bool = False,
                      stored_rim: bool = False) -> bool:
    """Whether a final look is vetoed by an address stored from looks whose TC is each
    (crease, measured) of ``stored`` (the other features alike, TK 0), the query's TC
    ``query_tc``; ``rim``/``stored_rim``: the query's/the stored looks' pad lay flat over
    a top's rim (TR known)."""
    cfg = config or MemoryConfig.for_mode("extended")
    names = feature_names("extended")
    tc, tk, tr = names.index("TC"), names.index("TK"), names.index("TR")
    known = np.ones(len(names), bool)
    known[tr] = False  # a prism's top never lies flat under the pad
    x = np.full(len(names), 0.4)
    x[tk] = 0.0
    memory = AssociativeMemory(cfg, seed=3)
    looks = []
    for crease, measured in stored:
        look, k = x.copy(), known.copy()
        look[tc], k[tc], k[tr] = crease, measured, stored_rim
        looks.append((look, k))
    # The earlier looks of one focus, then its store: the address holds them all.
    for look, k in looks[:-1]:
        memory.decide(look, k, focus_id=1)
    address = memory.store(*looks[-1], focus_id=1)
    assert len(memory.exemplars(address)) == len(looks)
    q, k = x.copy(), known.copy()
    q[tc] = query_tc
    k[tr] = rim
    return memory.decide(q, k, final_trial=True).vetoed


def test_a_crease_found_is_not_an_address_that_never_found_one() -> None:
    """One-sided (``crease_found_veto``): a query whose touches found a crease (a prism's
    ridge) is turned down by an address none of whose looks found one, wherever the other
    features put it; a query that found none is not turned down by an address that did
    (its probes may have stayed on one flank), nor is any query by an address one of whose
    looks found a crease or whose looks never measured one, nor a query whose pad lay flat
    over a top's rim (TR known: a flat top's rim is a crease too)."""
    cfg = MemoryConfig.for_mode("extended")
    decide = _touched_decision
    assert decide([(0.1, True)], 1.0) is True
    assert decide([(0.1, True)], 1.0,
                  dataclasses.replace(cfg, crease_found_veto=False)) is False
    assert decide([(1.0, True)], 0.1) is False
    assert decide([(0.1, True), (1.0, True)], 1.0) is False
    assert decide([(0.1, False)], 1.0) is False
    assert decide([(0.1, True)], 0.3) is False
    assert decide([(0.1, True)], 1.0, rim=True) is False
    # The paper mode has no TC: the rule has nothing to read there.
    assert "TC" not in feature_names("paper")


def test_a_flat_rim_felt_is_not_an_address_that_only_found_creases() -> None:
    """The mirror (``rim_found_veto``): random 10141's 0.08 m cylinders, whose pads lay
    flat over the top's rim (TR known) and found no crease, were taken for the prism stored
    first (TC 1.0, no rim), close in size, grey and weight. Turned down now; not by an
    address one of whose looks found no crease, or felt a rim, or never measured TC, and
    never a query that felt no rim (none found is no evidence of none) or found a
    crease."""
    cfg = MemoryConfig.for_mode("extended")
    decide = _touched_decision
    assert decide([(1.0, True)], 0.1, rim=True) is True
    assert decide([(1.0, True), (0.9, True)], 0.1, rim=True) is True
    assert decide([(1.0, True)], 0.1, dataclasses.replace(cfg, rim_found_veto=False),
                  rim=True) is False
    assert decide([(1.0, True)], 0.1) is False
    assert decide([(1.0, True)], 1.0, rim=True) is False
    assert decide([(1.0, True), (0.1, True)], 0.1, rim=True) is False
    assert decide([(1.0, False)], 0.1, rim=True) is False
    assert decide([(1.0, True)], 0.1, rim=True, stored_rim=True) is False


def _stored_then_asked(cfg: MemoryConfig, x: np.ndarray, q: np.ndarray, known: np.ndarray,
                       hidden: int) -> tuple[Decision, bool]:
    """A memory that stored ``x``: its final-trial decision on ``q``, then whether it
    vetoes ``q`` with the feature ``hidden`` unknown."""
    memory = AssociativeMemory(cfg, seed=3)
    memory.store(x, known)
    decision = memory.decide(q, known, final_trial=True)
    unknown = known.copy()
    unknown[hidden] = False
    return decision, memory.decide(q, unknown, final_trial=True).vetoed


def test_the_grey_vetoes_closer_between_two_straight_edged_flat_tops() -> None:
    """Two boxes of one size and weight, 16 greys apart (A 0.054), differ too little in A
    for the veto between flat tops (a cylinder's lit side spreads its copies' A) and the
    cap keeps them within the acceptance distance. Between two flat looks whose outlines
    are both straight-edged (O >= ``straight_outline``: a box's top, one grey wherever it
    stands) A vetoes at ``straight_veto``. Between two round outlines (cylinders), or one
    of each, or where one outline is unknown, it does not."""
    cfg = MemoryConfig.for_mode("extended")
    names = feature_names("extended")
    o, a, tc, tk = (names.index(n) for n in ("O", "A", "TC", "TK"))
    assert cfg.straight_veto[a] < 0.054 < cfg.flat_veto[a]
    assert all(v >= 1.0 for i, v in enumerate(cfg.straight_veto) if i != a)
    box, cylinder = cfg.straight_outline + 0.05, cfg.straight_outline - 0.06
    # A round outline just under the split: O alone, 0.04 from the box's, does not veto.
    round_near = cfg.straight_outline - 0.01
    assert box - round_near < cfg.flat_veto[o]
    known = np.ones(len(names), bool)
    for what, outline, query_outline, vetoed in (("two boxes", box, box, True),
                                                 ("two cylinders", cylinder, cylinder, False),
                                                 ("stored box, round query", box,
                                                  round_near, False)):
        x = np.full(len(names), 0.4)
        x[tc], x[tk], x[o], x[a] = 0.1, 0.0, outline, 0.22
        q = x.copy()
        q[o], q[a] = query_outline, 0.166
        # Without the query's outline, its top is not known to be straight-edged.
        decision, vetoed_unknown = _stored_then_asked(cfg, x, q, known, o)
        assert decision.distance < cfg.identify_distance, what
        assert decision.vetoed is vetoed, what
        assert vetoed_unknown is False, what
    # In the paper mode the rule has nothing to read (no outline, no touch).
    assert all(v >= 1.0 for v in MemoryConfig.for_mode("paper").straight_veto)


def test_a_spheres_albedo_vetoes_between_two_looks_the_hand_found_curved() -> None:
    """Two spheres of one size and weight a Table-1 step of grey apart (72 and 87: AS
    0.059 apart) lie within the acceptance distance: AS varies with the view for every
    other shape, so it never vetoes at large. Between two looks the hand found smooth and
    curved (TC < ``flat_crease``, TK >= ``flat_curvature``: a sphere) it vetoes at
    ``curved_veto``; between two flat tops, or where the query's curvature is unknown, it
    does not."""
    cfg = MemoryConfig.for_mode("extended")
    names = feature_names("extended")
    a_s, tc, tk = (names.index(n) for n in ("AS", "TC", "TK"))
    step = 15.0 / 255.0
    assert cfg.curved_veto[a_s] < step
    assert all(v >= 1.0 for i, v in enumerate(cfg.curved_veto) if i != a_s)
    assert cfg.veto[a_s] >= 1.0 and cfg.flat_veto[a_s] >= 1.0
    known = np.ones(len(names), bool)
    for what, curvature, vetoed in (("two spheres", 0.5, True), ("two flat tops", 0.0, False)):
        x = np.full(len(names), 0.4)
        x[tc], x[tk], x[a_s] = 0.1, curvature, 72.0 / 255.0
        q = x.copy()
        q[a_s] += step
        decision, vetoed_unknown = _stored_then_asked(cfg, x, q, known, tk)
        assert decision.distance < cfg.identify_distance, what
        assert decision.vetoed is vetoed, what
        assert vetoed_unknown is False, what
    # In the paper mode there is no AS and no touch.
    assert all(v >= 1.0 for v in MemoryConfig.for_mode("paper").curved_veto)


@pytest.mark.parametrize("feature", ["O", "A", "I1"])
def test_the_outline_and_brightest_grey_count_not_between_two_looks_the_hand_found_creased(
        feature: str) -> None:
    """A prism's outline O turns with its yaw (0.2-0.85), and so do its brightest face's
    grey A and the paper's rim contrast and texture I, T (its lit flank turns against the
    one light; AP, the albedo of its touched faces, carries its grey instead): between two
    looks whose touches crossed a crease (TC >= flat_crease) they are left out of the
    distance, in the network and in the memory's own distance alike; between a creased and
    an uncreased look, or two uncreased ones, they count."""
    cfg = MemoryConfig.for_mode("extended")
    names = feature_names("extended")
    o, tc, tk = names.index(feature), names.index("TC"), names.index("TK")
    assert cfg.creased_unused == ("O", "A", "I1", "I2", "I3", "T1", "T2", "T3")
    known = np.ones(len(names), bool)
    x = np.full(len(names), 0.4)
    x[tk], x[o] = 0.0, 0.2
    far = 0.2 + 5.5 * np.sqrt(2.0) * cfg.feature_scale[o]  # at the cap: the most it adds
    results = {}
    for crease_stored, crease_query in ((1.0, 1.0), (1.0, 0.3), (0.3, 0.3)):
        memory = AssociativeMemory(cfg, seed=3)
        stored = x.copy()
        stored[tc] = crease_stored
        memory.store(stored, known)
        q = x.copy()
        q[tc], q[o] = crease_query, far
        same_o = q.copy()
        same_o[o] = 0.2
        results[(crease_stored, crease_query)] = (
            float(memory.distances(q, known)[0]), float(memory.distances(same_o, known)[0]),
            memory.decide(q, known, final_trial=True).distance)
    both, one, none = results[(1.0, 1.0)], results[(1.0, 0.3)], results[(0.3, 0.3)]
    # Both creased: the feature's difference adds nothing (the memory's distance and the
    # network's).
    assert both[0] == pytest.approx(both[1], abs=1e-6)
    assert both[2] == pytest.approx(both[0], rel=0.05, abs=0.05)
    # One or neither creased: it counts.
    assert one[0] > one[1] + 0.5 and none[0] > none[1] + 0.5
    assert one[2] > both[2] + 0.5 and none[2] > both[2] + 0.5
    # The paper mode has no crease to read.
    assert MemoryConfig.for_mode("paper").creased_unused == ()


def test_a_store_keeps_the_looks_of_its_focus_that_show_the_same_object() -> None:
    x = _distinct_patterns(2, seed=16)
    rng = np.random.default_rng(6)
    memory = AssociativeMemory(CONFIG, seed=4)
    # Repeats well inside the acceptance distance (5 % of the robot's repeat pairs lie
    # beyond it, and are left out by design): the test is about the other object.
    shift, visual = _look(x[0], rng, 0.5), _look(x[0], rng, 0.5)
    other = _look(x[1], rng)  # the focus slid onto another object for one look
    haptic = _look(x[0], rng, 0.5)
    for q, k in ((shift, W_UNKNOWN), (other, W_UNKNOWN), (visual, W_UNKNOWN)):
        memory.match(np.where(k, q, 0), k, focus_id=7)
    memory.match(haptic, ALL_KNOWN, final_trial=True, focus_id=7)
    address = memory.store(haptic, ALL_KNOWN, focus_id=7)
    looks = memory.exemplars(address)
    assert len(looks) == 3  # shift, visual, haptic; not the other object
    assert memory.exemplar_known(address).all()  # W completed from the haptic look
    np.testing.assert_allclose(looks[:, WEIGHT_INDEX], haptic[WEIGHT_INDEX])
    np.testing.assert_allclose(looks[-1], haptic)
    # Another focus id: only the store's own features.
    assert len(memory.exemplars(memory.store(other, ALL_KNOWN, focus_id=8))) == 1


def test_two_looks_of_a_focus_that_complete_to_one_are_stored_once() -> None:
    # The haptic look measured W and nothing else new (its ROI was cut by the retina's
    # edge, so the focus kept the visual look's features): completed with W, the visual
    # look equals it. The store's own features came from a later frame.
    x = _distinct_patterns(1, seed=19)[0]
    rng = np.random.default_rng(9)
    visual = _look(x, rng, 0.5)
    after = _look(x, rng, 0.5)
    after[WEIGHT_INDEX] = visual[WEIGHT_INDEX]  # one weighing: every later frame carries it
    memory = AssociativeMemory(CONFIG, seed=7)
    memory.match(np.where(W_UNKNOWN, visual, 0), W_UNKNOWN, focus_id=3)
    memory.match(visual, ALL_KNOWN, final_trial=True, focus_id=3)
    looks = memory.exemplars(memory.store(after, ALL_KNOWN, focus_id=3))
    assert len(looks) == 2, looks
    assert len(np.unique(looks, axis=0)) == 2


def test_refinement_reaches_one_acceptance_radius_and_does_not_chain() -> None:
    """Objects on a line 0.8 tau apart: B is identified as A and refines A (a stored
    look of A accepts it); C is identified through B's look, but does not refine A (no
    stored look of A accepts it); D, 0.8 tau beyond C, is then new."""
    tau = CONFIG.identify_distance
    rng = np.random.default_rng(8)
    a = _distinct_patterns(1, seed=17)[0]
    step = _moved(a, 0.8 * tau, rng) - a
    b, c, d = a + step, a + 2 * step, a + 3 * step
    memory = AssociativeMemory(CONFIG, seed=5)
    memory.store(a, ALL_KNOWN, focus_id=1)
    rb = memory.match(b, ALL_KNOWN, final_trial=True, focus_id=2)
    assert (rb.outcome, rb.address, len(memory.exemplars(0))) == (
        MatchOutcome.IDENTIFIED, 0, 2)
    rc = memory.match(c, ALL_KNOWN, final_trial=True, focus_id=3)
    assert (rc.outcome, len(memory.exemplars(0))) == (MatchOutcome.IDENTIFIED, 2)
    rd = memory.match(d, ALL_KNOWN, final_trial=True, focus_id=4)
    assert rd.outcome == MatchOutcome.NEW
    assert memory.stats.refinements == 1


def test_a_feature_only_refined_looks_know_does_not_veto() -> None:
    """An address stored without D (its object's silhouette cut by a nearer one) is
    identified from a look that knows D, which refines it. That one D is unvouched (the
    refinement was accepted on the features the stored looks know): a later look whose D
    differs from it by more than D's veto must not be turned down for it (yaw 10122's box
    c07_0: D 0.163 against a refined 0.111, vetoed and stored a second time;
    docs/memory.md). The refined look keeps its D for the network's distance."""
    d = FEATURE_NAMES.index("D")
    without_d = ALL_KNOWN.copy()
    without_d[d] = False
    rng = np.random.default_rng(31)
    a = _distinct_patterns(1, seed=23)[0]
    memory = AssociativeMemory(CONFIG, seed=9)
    memory.store(a, without_d, focus_id=1)
    seen = _look(a, rng, 0.3)
    seen[d] = a[d] - 0.05
    first = memory.match(seen, ALL_KNOWN, final_trial=True, focus_id=2)
    assert (first.outcome, first.address) == (MatchOutcome.IDENTIFIED, 0)
    assert memory.stats.refinements == 1
    assert memory.exemplar_known(0)[:, d].tolist() == [False, True]
    again = _look(a, rng, 0.3)
    again[d] = a[d] + 0.05  # 0.10 from the refined look's D: beyond D's veto
    assert abs(again[d] - seen[d]) > memory.config.veto[d]
    second = memory.match(again, ALL_KNOWN, final_trial=True, focus_id=3)
    assert (second.outcome, second.address) == (MatchOutcome.IDENTIFIED, 0)
    assert memory.stats.vetoes == 0


def test_refinement_is_capped() -> None:
    x = _distinct_patterns(1, seed=18)[0]
    memory = AssociativeMemory(MemoryConfig.for_mode("paper", refine_looks=3), seed=6)
    memory.store(x, ALL_KNOWN, focus_id=1)
    rng = np.random.default_rng(9)
    for focus in range(2, 12):
        memory.match(_look(x, rng, 0.3), ALL_KNOWN, final_trial=True, focus_id=focus)
    assert len(memory.exemplars(0)) == 3


def test_empty_memory() -> None:
    memory = AssociativeMemory(CONFIG)
    q = np.full(FEATURE_DIM, 0.5)
    assert memory.size == 0
    assert memory.match(q, ALL_KNOWN).outcome == MatchOutcome.UNDETERMINED
    assert memory.match(q, ALL_KNOWN, final_trial=True).outcome == MatchOutcome.NEW


def test_hundred_stored_objects_all_recalled() -> None:
    patterns = np.random.default_rng(21).random((100, FEATURE_DIM)).astype(np.float32)
    memory = AssociativeMemory(CONFIG, seed=4)
    memory.store_many(patterns, np.ones((100, FEATURE_DIM), bool))
    rng = np.random.default_rng(22)
    results = [memory.match(_look(p, rng, 0.5), ALL_KNOWN) for p in patterns]
    assert [r.address for r in results] == list(range(100))
    assert sum(r.outcome == MatchOutcome.IDENTIFIED for r in results) >= 95


def test_same_seed_same_memory_other_seed_differs() -> None:
    x = _distinct_patterns(3, seed=19)

    def build(seed: int) -> AssociativeMemory:
        memory = AssociativeMemory(CONFIG, seed=seed)
        for p in x:
            memory.store(p, ALL_KNOWN)
        return memory

    a, b, c = build(7), build(7), build(8)
    assert torch.equal(a.network.centres, b.network.centres)
    assert torch.equal(a.network.log_scale, b.network.log_scale)
    assert not torch.equal(a.network.log_scale, c.network.log_scale)


def test_handle_store_and_match() -> None:
    memory = AssociativeMemory(CONFIG, seed=5)
    x = _distinct_patterns(2, seed=20)
    replies = [memory.handle(MemoryRequest(i, MemoryOp.STORE, p, ALL_KNOWN, focus_id=i + 1))
               for i, p in enumerate(x)]
    assert [(r.outcome, r.address, r.confidence) for r in replies] == [
        (MatchOutcome.NEW, 0, 1.0), (MatchOutcome.NEW, 1, 1.0)]
    match = memory.handle(MemoryRequest(2, MemoryOp.MATCH, x[1], ALL_KNOWN))
    assert match == memory.match(x[1], ALL_KNOWN)
    assert (match.outcome, match.address) == (MatchOutcome.IDENTIFIED, 1)
    final = memory.handle(MemoryRequest(3, MemoryOp.MATCH, 1.0 - x[1], ALL_KNOWN, True))
    assert final.outcome == MatchOutcome.NEW
    with pytest.raises(IndexError):
        memory.exemplars(2)


def test_table1_objects_with_their_weights() -> None:
    """The paper's Table 1 (perceived I, D, W of objects 01-04, the rest equal): 01, 02,
    04 are each identified as themselves; 03 (grey 69 next to 02's 79) is within the
    robot's category-level intensity spread of 02, so only its weight can make it new:
    lighter than 02's by 0.8 vetoes it is identified as 02, by 1.25 vetoes it is new.
    The paper's 0.47 vs 0.51 lies on the edge of the robot's measured weighing noise
    (0.04 against a calibrated veto of 0.038-0.040, about 3 sigma of the difference of
    two weighings, docs/memory.md): it goes to whichever side of the veto it falls. With
    W unknown vision cannot exclude 02 or 04."""
    def table1(intensity: float, size: float, weight: float) -> np.ndarray:
        x = np.full(FEATURE_DIM, 0.3, np.float32)
        x[[FEATURE_NAMES.index(n) for n in ("I1", "I2", "I3")]] = intensity
        x[FEATURE_NAMES.index("D")] = size
        x[WEIGHT_INDEX] = weight
        return x

    objects = [table1(0.83, 0.45, 0.72), table1(0.65, 0.43, 0.51),
               table1(0.56, 0.44, 0.47), table1(0.47, 0.44, 0.24)]
    memory = AssociativeMemory(CONFIG, seed=3)
    for i in (0, 1, 3):
        memory.store(objects[i], ALL_KNOWN)
    for address, i in enumerate((0, 1, 3)):
        result = memory.match(objects[i], ALL_KNOWN)
        assert (result.outcome, result.address) == (MatchOutcome.IDENTIFIED, address)
    veto = CONFIG.veto[WEIGHT_INDEX]
    lighter = table1(0.56, 0.44, 0.51 - 1.25 * veto)
    assert memory.match(lighter, ALL_KNOWN, final_trial=True).outcome == MatchOutcome.NEW
    paper_03 = memory.match(objects[2], ALL_KNOWN, final_trial=True)
    expected = (MatchOutcome.NEW, -1) if 0.04 > veto else (MatchOutcome.IDENTIFIED, 1)
    assert (paper_03.outcome, paper_03.address) == expected
    assert memory.match(objects[2], W_UNKNOWN).outcome == MatchOutcome.UNDETERMINED
    assert memory.match(objects[2], W_UNKNOWN, final_trial=True).address in (1, 2)
    # Last: an identification refines the address with the query's look.
    near = memory.match(table1(0.56, 0.44, 0.51 - 0.8 * veto), ALL_KNOWN, final_trial=True)
    assert (near.outcome, near.address) == (MatchOutcome.IDENTIFIED, 1)


@pytest.mark.parametrize(("features", "known"), [
    (np.zeros(FEATURE_DIM - 1), np.ones(FEATURE_DIM - 1, bool)),
    (np.full(FEATURE_DIM, np.nan), ALL_KNOWN),
])
def test_bad_patterns_are_refused(features: np.ndarray, known: np.ndarray) -> None:
    memory = AssociativeMemory(CONFIG)
    with pytest.raises(MessageError):
        memory.match(features, known)
    with pytest.raises(MessageError):
        memory.store(features, known)


def test_nothing_known_cannot_be_stored_but_unknown_nan_is_fine() -> None:
    memory = AssociativeMemory(CONFIG)
    with pytest.raises(MessageError):
        memory.store(np.zeros(FEATURE_DIM), np.zeros(FEATURE_DIM, bool))
    q = np.full(FEATURE_DIM, 0.5)
    q[WEIGHT_INDEX] = np.nan
    assert memory.store(q, W_UNKNOWN) == 0
    assert memory.match(q, W_UNKNOWN, final_trial=True).outcome == MatchOutcome.IDENTIFIED
