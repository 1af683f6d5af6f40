"""Saving and loading the long-term memory: round trip, atomic writes, refused files."""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
import pytest
import torch

from roger_common.errors import MemoryFileError
from roger_common.types import FEATURE_DIM, WEIGHT_INDEX, MatchOutcome, feature_dim
from roger_memory import persistence
from roger_memory.config import MemoryConfig
from roger_memory.memory import AssociativeMemory

ALL_KNOWN = np.ones(FEATURE_DIM, bool)
PAPER = MemoryConfig.for_mode("paper")  # these tests build paper-mode (11) looks
W_UNKNOWN = ALL_KNOWN.copy()
W_UNKNOWN[WEIGHT_INDEX] = False
PATTERNS = np.random.default_rng(31).random((4, FEATURE_DIM)).astype(np.float32)


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _named(path: Path, problem: str) -> str:
    """Pattern of an error message that names ``path`` and then states ``problem``."""
    return re.escape(str(path)) + ".*" + re.escape(problem)


def _memory(n: int, seed: int = 0) -> AssociativeMemory:
    memory = AssociativeMemory(PAPER, seed=seed)
    for p in PATTERNS[:n]:
        memory.store(p, ALL_KNOWN)
    return memory


@pytest.fixture(scope="module")
def three() -> AssociativeMemory:
    return _memory(3)


def _queries() -> list[tuple[np.ndarray, np.ndarray, bool]]:
    rng = np.random.default_rng(32)
    noisy = [np.clip(p + rng.normal(0, 0.01, FEATURE_DIM), 0, 1) for p in PATTERNS]
    return [(q, k, final) for q in [*noisy, rng.random(FEATURE_DIM)]
            for k in (ALL_KNOWN, W_UNKNOWN) for final in (False, True)]


def test_saved_and_loaded_memory_recalls_the_same(three, tmp_path: Path) -> None:
    path = tmp_path / "ltm.bin"
    three.save(path)
    loaded = AssociativeMemory.load(path)
    assert loaded.size == three.size == 3
    assert loaded.config == three.config and loaded.seed == three.seed
    for address in range(3):
        np.testing.assert_array_equal(loaded.exemplars(address), three.exemplars(address))
        np.testing.assert_array_equal(loaded.exemplar_known(address),
                                      three.exemplar_known(address))
    for (name, a), (_, b) in zip(three.network.state_dict().items(),
                                 loaded.network.state_dict().items(), strict=True):
        assert torch.equal(a, b), name
    for q, k, final in _queries():
        assert loaded.match(q, k, final) == three.match(q, k, final)
    assert loaded.match(PATTERNS[1], ALL_KNOWN).address == 1


def test_storing_after_a_load_continues_as_without_it(tmp_path: Path) -> None:
    path = tmp_path / "ltm.bin"
    _memory(2, seed=3).save(path)
    resumed = AssociativeMemory.load(path)
    assert resumed.store(PATTERNS[2], ALL_KNOWN) == 2
    direct = _memory(3, seed=3)
    for (name, a), (_, b) in zip(direct.network.state_dict().items(),
                                 resumed.network.state_dict().items(), strict=True):
        assert torch.equal(a, b), name


def test_cut_off_file_refused_and_previous_good_file_still_loads(three, tmp_path: Path) -> None:
    good = tmp_path / "ltm.bin"
    three.save(good)
    data = good.read_bytes()
    cut = tmp_path / "cut.bin"
    for length in (0, 10, 30, len(data) // 2, len(data) - 1):
        cut.write_bytes(data[:length])
        with pytest.raises(MemoryFileError, match=_named(cut, "cut off")):
            AssociativeMemory.load(cut)
    assert AssociativeMemory.load(good).match(PATTERNS[0], ALL_KNOWN).address == 0


def test_crash_during_save_leaves_old_memory(three, tmp_path: Path, monkeypatch) -> None:
    path = tmp_path / "ltm.bin"
    three.save(path)
    before = path.read_bytes()
    bigger = _memory(4)

    def crash(*args, **kwargs):
        raise OSError("simulated crash before the rename")

    monkeypatch.setattr(os, "replace", crash)
    with pytest.raises(OSError, match="simulated"):
        bigger.save(path)
    monkeypatch.undo()
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ltm.bin"]  # no temp file left
    assert AssociativeMemory.load(path).size == 3
    bigger.save(path)
    assert AssociativeMemory.load(path).size == 4


def test_corrupt_files_are_refused_with_their_name(three, tmp_path: Path) -> None:
    data = bytearray(persistence.encode_snapshot(three.snapshot()))
    flipped = tmp_path / "flipped.bin"
    data[-5] ^= 0xFF
    flipped.write_bytes(bytes(data))
    with pytest.raises(MemoryFileError, match=_named(flipped, "checksum")):
        AssociativeMemory.load(flipped)
    text = tmp_path / "notes.txt"
    text.write_text("hello, this is not a memory file")
    with pytest.raises(MemoryFileError, match=_named(text, "not a Roger")):
        AssociativeMemory.load(text)
    with pytest.raises(MemoryFileError, match=_named(tmp_path / "missing.bin", "cannot read")):
        AssociativeMemory.load(tmp_path / "missing.bin")


def test_incompatible_files_are_refused(three, tmp_path: Path, monkeypatch) -> None:
    path = tmp_path / "ltm.bin"
    three.save(path)
    monkeypatch.setattr(persistence, "FORMAT_VERSION", 99)
    with pytest.raises(MemoryFileError, match=_named(path, "format version 2")):
        AssociativeMemory.load(path)
    monkeypatch.undo()
    monkeypatch.setattr(persistence, "feature_names", lambda mode: ("I1",) * FEATURE_DIM)
    other = tmp_path / "other.bin"
    three.save(other)
    monkeypatch.undo()
    with pytest.raises(MemoryFileError, match=_named(other, "incompatible feature layout")):
        AssociativeMemory.load(other)


def test_load_with_other_thresholds_is_allowed(three, tmp_path: Path) -> None:
    path = tmp_path / "ltm.bin"
    three.save(path)
    strict = MemoryConfig.for_mode("paper", veto=(1e-6,) * FEATURE_DIM)
    loaded = AssociativeMemory.load(path, strict)
    assert loaded.config == strict
    q = np.clip(PATTERNS[0] + 0.01, 0, 1)
    assert loaded.match(q, ALL_KNOWN, final_trial=True).outcome == MatchOutcome.NEW
    assert three.match(q, ALL_KNOWN, final_trial=True).outcome == MatchOutcome.IDENTIFIED


def test_open_starts_empty_then_loads(three, tmp_path: Path) -> None:
    path = tmp_path / "sub" / "ltm.bin"
    fresh = AssociativeMemory.open(path, seed=9)
    assert (fresh.size, fresh.seed) == (0, 9)
    three.save(path)
    assert AssociativeMemory.open(path).size == 3
    path.write_bytes(b"garbage, not a memory file")
    with pytest.raises(MemoryFileError, match=_named(path, "not a Roger")):
        AssociativeMemory.open(path)


def test_empty_memory_round_trips(tmp_path: Path) -> None:
    path = tmp_path / "empty.bin"
    AssociativeMemory(PAPER, seed=4).save(path)
    loaded = AssociativeMemory.load(path)
    assert (loaded.size, loaded.seed) == (0, 4)
    assert loaded.store(PATTERNS[0], ALL_KNOWN) == 0



def test_a_memory_of_one_feature_mode_is_refused_by_the_other(three, tmp_path: Path) -> None:
    path = tmp_path / "paper.bin"
    three.save(path)
    with pytest.raises(MemoryFileError, match=_named(path, "paper-mode features")
                       + ".*--features paper"):
        AssociativeMemory.load(path, MemoryConfig.for_mode("extended"))
    extended = AssociativeMemory(MemoryConfig.for_mode("extended"), seed=1)
    extended.store(np.full(feature_dim("extended"), 0.5, np.float32),
                   np.ones(feature_dim("extended"), bool))
    other = tmp_path / "extended.bin"
    extended.save(other)
    with pytest.raises(MemoryFileError, match=_named(other, "extended-mode features")):
        AssociativeMemory.load(other, PAPER)
    back = AssociativeMemory.load(other)
    assert back.config.features == "extended" and back.size == 1
    # The file says its layout: the feature names of its mode.
    assert persistence.load_snapshot(other).config["features"] == "extended"
