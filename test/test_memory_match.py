"""Match and store in the associative memory: the three outcomes of section 4.2."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from roger_common.errors import MessageError
from roger_common.types import (
    FEATURE_DIM,
    FEATURE_NAMES,
    WEIGHT_INDEX,
    MatchOutcome,
    MemoryOp,
    MemoryRequest,
)
from roger_memory.memory import AssociativeMemory

ALL_KNOWN = np.ones(FEATURE_DIM, bool)
W_UNKNOWN = ALL_KNOWN.copy()
W_UNKNOWN[WEIGHT_INDEX] = False
NOISE = 0.01


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _distinct_patterns(n: int, seed: int) -> np.ndarray:
    x = np.random.default_rng(seed).random((n, FEATURE_DIM)).astype(np.float32)
    rms = np.sqrt(((x[:, None] - x[None]) ** 2).mean(axis=2))
    assert rms[~np.eye(n, dtype=bool)].min() > 0.1  # the patterns really are distinct
    return x


def _noisy(x: np.ndarray, rng: np.random.Generator, std: float = NOISE) -> np.ndarray:
    return np.clip(x + rng.normal(0.0, std, x.shape), 0.0, 1.0)


def _table1(intensity: float, size: float, weight: float) -> np.ndarray:
    """An object of Table 1: the same shape and texture, its own I, D and W."""
    x = np.full(FEATURE_DIM, 0.3, np.float32)
    x[[FEATURE_NAMES.index(n) for n in ("I1", "I2", "I3")]] = intensity
    x[FEATURE_NAMES.index("D")] = size
    x[WEIGHT_INDEX] = weight
    return x


@pytest.fixture(scope="module")
def ten() -> tuple[AssociativeMemory, np.ndarray]:
    patterns = _distinct_patterns(10, seed=11)
    memory = AssociativeMemory(seed=0)
    addresses = [memory.store(p, ALL_KNOWN) for p in patterns]
    assert addresses == list(range(10))
    return memory, patterns


@pytest.fixture(scope="module")
def weight_pair() -> tuple[AssociativeMemory, np.ndarray]:
    """Four objects; 1 and 2 differ only in weight (0.30 vs 0.55)."""
    x = _distinct_patterns(4, seed=12)
    x[2] = x[1]
    x[1, WEIGHT_INDEX], x[2, WEIGHT_INDEX] = 0.30, 0.55
    memory = AssociativeMemory(seed=1)
    for p in x:
        memory.store(p, ALL_KNOWN)
    return memory, x


@pytest.mark.parametrize("std", [0.0, 0.01, 0.02])
def test_ten_stored_patterns_are_each_identified(ten, std: float) -> None:
    memory, patterns = ten
    rng = np.random.default_rng(int(std * 1000))
    assert memory.size == 10
    for address, p in enumerate(patterns):
        result = memory.match(_noisy(p, rng, std), ALL_KNOWN)
        assert result.outcome == MatchOutcome.IDENTIFIED, (address, result)
        assert result.address == address
        assert memory.config.confidence_threshold <= result.confidence <= 1.0


def test_unseen_pattern_is_not_identified(ten) -> None:
    memory, patterns = ten
    rng = np.random.default_rng(99)
    for _ in range(20):
        unseen = rng.random(FEATURE_DIM)
        if np.sqrt(((patterns - unseen) ** 2).mean(axis=1)).min() < 0.1:
            continue
        assert memory.match(unseen, ALL_KNOWN).outcome == MatchOutcome.UNDETERMINED
        final = memory.match(unseen, ALL_KNOWN, final_trial=True)
        assert (final.outcome, final.address) == (MatchOutcome.NEW, -1)
    assert memory.size == 10  # a NEW outcome does not store by itself


def test_final_trial_is_never_undetermined(ten) -> None:
    memory, patterns = ten
    rng = np.random.default_rng(5)
    queries = [_noisy(p, rng, 0.05) for p in patterns] + list(rng.random((10, FEATURE_DIM)))
    for q in queries:
        for known in (ALL_KNOWN, W_UNKNOWN):
            result = memory.match(q, known, final_trial=True)
            assert result.outcome != MatchOutcome.UNDETERMINED
            assert (result.address >= 0) == (result.outcome == MatchOutcome.IDENTIFIED)


def test_match_does_not_change_the_memory(ten) -> None:
    memory, patterns = ten
    weights = memory.network.output.weight.detach().clone()
    memory.match(patterns[0], ALL_KNOWN)
    memory.match(patterns[1], ALL_KNOWN, final_trial=True)
    assert torch.equal(memory.network.output.weight, weights)
    assert all(len(memory.exemplars(a)) == 1 for a in range(memory.size))


@pytest.mark.parametrize("which", [1, 2])
def test_weight_only_difference_undetermined_then_told_apart(weight_pair, which: int) -> None:
    memory, x = weight_pair
    rng = np.random.default_rng(which)
    q = _noisy(x[which], rng)
    before = memory.match(np.where(W_UNKNOWN, q, 0.0), W_UNKNOWN)
    assert before.outcome == MatchOutcome.UNDETERMINED
    after = memory.match(q, ALL_KNOWN)
    assert (after.outcome, after.address) == (MatchOutcome.IDENTIFIED, which)
    final = memory.match(q, W_UNKNOWN, final_trial=True)
    assert (final.outcome, final.address in (1, 2)) == (MatchOutcome.IDENTIFIED, True)


def test_other_objects_identified_with_weight_unknown(weight_pair) -> None:
    memory, x = weight_pair
    rng = np.random.default_rng(8)
    for address in (0, 3):
        result = memory.match(_noisy(x[address], rng), W_UNKNOWN)
        assert (result.outcome, result.address) == (MatchOutcome.IDENTIFIED, address)


def test_unknown_weight_is_not_taken_as_zero() -> None:
    memory = AssociativeMemory(seed=2)
    x = _distinct_patterns(2, seed=13)
    x[:, WEIGHT_INDEX] = 0.6
    for p in x:
        memory.store(p, ALL_KNOWN)
    q = x[0].copy()
    q[WEIGHT_INDEX] = 0.0
    assert memory.match(q, W_UNKNOWN).address == 0
    assert memory.match(q, W_UNKNOWN).outcome == MatchOutcome.IDENTIFIED
    assert memory.match(q, ALL_KNOWN).outcome == MatchOutcome.UNDETERMINED
    assert memory.match(q, ALL_KNOWN, final_trial=True).outcome == MatchOutcome.NEW


def test_table1_objects_are_told_apart() -> None:
    # Table 1 of the paper: perceived intensity, size and weight of objects 01-04.
    objects = [_table1(0.83, 0.45, 0.72), _table1(0.65, 0.43, 0.51),
               _table1(0.56, 0.44, 0.47), _table1(0.47, 0.44, 0.24)]
    memory = AssociativeMemory(seed=3)
    for i in (0, 1, 3):
        memory.store(objects[i], ALL_KNOWN)
    rng = np.random.default_rng(4)
    for address, i in enumerate((0, 1, 3)):
        result = memory.match(_noisy(objects[i], rng), ALL_KNOWN)
        assert (result.outcome, result.address) == (MatchOutcome.IDENTIFIED, address)
    for known in (ALL_KNOWN, W_UNKNOWN):  # object 03 is new, though close to 02
        result = memory.match(_noisy(objects[2], rng), known, final_trial=True)
        assert result.outcome == MatchOutcome.NEW


def test_empty_memory() -> None:
    memory = AssociativeMemory()
    q = np.full(FEATURE_DIM, 0.5)
    assert memory.size == 0
    assert memory.match(q, ALL_KNOWN).outcome == MatchOutcome.UNDETERMINED
    assert memory.match(q, ALL_KNOWN, final_trial=True).outcome == MatchOutcome.NEW


def test_hundred_stored_objects_all_recalled() -> None:
    patterns = np.random.default_rng(21).random((100, FEATURE_DIM)).astype(np.float32)
    memory = AssociativeMemory(seed=4)
    for p in patterns:
        memory.store(p, ALL_KNOWN)
    rng = np.random.default_rng(22)
    results = [memory.match(_noisy(p, rng), ALL_KNOWN) for p in patterns]
    assert [r.address for r in results] == list(range(100))
    assert all(r.outcome == MatchOutcome.IDENTIFIED for r in results)


def test_same_seed_same_memory_other_seed_differs() -> None:
    x = _distinct_patterns(3, seed=14)

    def build(seed: int) -> AssociativeMemory:
        memory = AssociativeMemory(seed=seed)
        for p in x:
            memory.store(p, ALL_KNOWN)
        return memory

    a, b, c = build(7), build(7), build(8)
    assert torch.equal(a.network.output.weight, b.network.output.weight)
    assert not torch.equal(a.network.output.weight, c.network.output.weight)


def test_handle_store_and_match() -> None:
    memory = AssociativeMemory(seed=5)
    x = _distinct_patterns(2, seed=15)
    replies = [memory.handle(MemoryRequest(i, MemoryOp.STORE, p, ALL_KNOWN))
               for i, p in enumerate(x)]
    assert [(r.outcome, r.address, r.confidence) for r in replies] == [
        (MatchOutcome.NEW, 0, 1.0), (MatchOutcome.NEW, 1, 1.0)]
    match = memory.handle(MemoryRequest(2, MemoryOp.MATCH, x[1], ALL_KNOWN))
    assert match == memory.match(x[1], ALL_KNOWN)
    assert (match.outcome, match.address) == (MatchOutcome.IDENTIFIED, 1)
    final = memory.handle(MemoryRequest(3, MemoryOp.MATCH, 1.0 - x[1], ALL_KNOWN, True))
    assert final.outcome == MatchOutcome.NEW


def test_add_exemplar_refines_up_to_the_cap() -> None:
    memory = AssociativeMemory(seed=6)
    x = _distinct_patterns(2, seed=16)
    memory.store(x[0], W_UNKNOWN)
    memory.store(x[1], ALL_KNOWN)
    assert memory.add_exemplar(0, x[0], ALL_KNOWN)
    assert len(memory.exemplars(0)) == 2
    assert memory.exemplar_known(0)[1, WEIGHT_INDEX]
    for _ in range(memory.config.max_exemplars_per_address - 2):
        assert memory.add_exemplar(0, x[0], ALL_KNOWN)
    assert not memory.add_exemplar(0, x[0], ALL_KNOWN)
    assert memory.match(x[0], ALL_KNOWN).address == 0
    with pytest.raises(IndexError):
        memory.exemplars(2)


@pytest.mark.parametrize(("features", "known"), [
    (np.zeros(FEATURE_DIM - 1), np.ones(FEATURE_DIM - 1, bool)),
    (np.full(FEATURE_DIM, np.nan), ALL_KNOWN),
])
def test_bad_patterns_are_refused(features: np.ndarray, known: np.ndarray) -> None:
    memory = AssociativeMemory()
    with pytest.raises(MessageError):
        memory.match(features, known)
    with pytest.raises(MessageError):
        memory.store(features, known)


def test_nothing_known_cannot_be_stored_but_unknown_nan_is_fine() -> None:
    memory = AssociativeMemory()
    with pytest.raises(MessageError):
        memory.store(np.zeros(FEATURE_DIM), np.zeros(FEATURE_DIM, bool))
    q = np.full(FEATURE_DIM, 0.5)
    q[WEIGHT_INDEX] = np.nan
    assert memory.store(q, W_UNKNOWN) == 0
    assert memory.match(q, W_UNKNOWN).outcome == MatchOutcome.IDENTIFIED
