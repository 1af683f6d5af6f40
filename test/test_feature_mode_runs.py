"""The feature mode across a run: a memory file of the other mode is refused before anything
starts, query files say their mode, and the demo's side-by-side report holds both modes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from roger_common.errors import MemoryFileError
from roger_common.types import feature_dim
from roger_experiments.compare import CLAIMS, COLUMNS, SCORES, modes_markdown
from roger_experiments.record_queries import Query, columns, read_csv, write_csv
from roger_memory.config import MemoryConfig
from roger_memory.memory import AssociativeMemory


def _memory_file(path: Path, mode: str) -> Path:
    memory = AssociativeMemory(MemoryConfig.for_mode(mode), seed=0)
    memory.store(np.full(feature_dim(mode), 0.5, np.float32), np.ones(feature_dim(mode), bool))
    memory.save(path)
    return path


def test_a_run_refuses_a_memory_file_of_the_other_mode_before_it_starts(tmp_path: Path) -> None:
    from roger_bringup.run import check_files
    paper = _memory_file(tmp_path / "paper.pt", "paper")
    qtable = tmp_path / "none.json"
    check_files(paper, qtable, "paper")                      # its own mode: accepted
    with pytest.raises(MemoryFileError, match=r"paper-mode.*--features paper"):
        check_files(paper, qtable, "extended")
    extended = _memory_file(tmp_path / "extended.pt", "extended")
    with pytest.raises(MemoryFileError, match=r"extended-mode.*--features extended"):
        check_files(extended, qtable, "paper")


@pytest.mark.parametrize("mode", ["paper", "extended"])
def test_a_query_file_says_its_mode_in_its_columns(tmp_path: Path, mode: str) -> None:
    n = feature_dim(mode)
    rng = np.random.default_rng(3)
    rows = [Query("w", "straightforward", 0, c, "shift", c, 1, False, "o", "cat",
                  np.round(rng.random(n), 4).astype(np.float32), rng.random(n) > 0.3)
            for c in range(3)]
    path = tmp_path / "q.csv.gz"
    write_csv(rows, path)
    back = read_csv(path)
    assert [len(q.features) for q in back] == [n] * 3
    for a, b in zip(rows, back, strict=True):
        assert np.array_equal(a.known, b.known)
        assert np.allclose(np.where(a.known, a.features, 0.0), b.features, atol=1e-4)
    other = "paper" if mode == "extended" else "extended"
    assert columns(mode) != columns(other)
    mixed = rows + [Query("w", "s", 0, 9, "shift", 9, 1, False, "o", "c",
                          np.zeros(feature_dim(other), np.float32),
                          np.ones(feature_dim(other), bool))]
    with pytest.raises(ValueError, match="several feature modes"):
        write_csv(mixed, tmp_path / "mixed.csv")


def test_the_side_by_side_report_holds_both_modes_and_every_claim() -> None:
    def result(shift: float) -> dict:
        cell = {"mean": 10.0 + shift, "sd": 1.0, "n": 3}
        row = {c: cell for c in (*COLUMNS, *SCORES)}
        claims = [{"claim": text, "verdict": f"v{shift:g}", "holds_in": 1, "seeds": 3}
                  for _, _, text in CLAIMS]
        return {"table2": {"qlearning": row, "straightforward": row}, "claims": claims,
                "completion": None}
    text = modes_markdown({"extended": result(1.0), "paper": result(2.0)}, "worlds/w.yaml")
    assert "`worlds/w.yaml`" in text
    for policy in ("Q-learning (1)", "simple (2)"):
        assert f"| {policy} | extended | 11.0 ± 1.0" in text
        assert f"| {policy} | paper | 12.0 ± 1.0" in text
    for _, _, claim in CLAIMS:
        assert f"| {claim} | v1 (1/3) | v2 (1/3) |" in text
