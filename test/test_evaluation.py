"""Ground-truth scoring on hand-made cycle logs, and the claim statistics of compare."""

from __future__ import annotations

import json

import numpy as np
import pytest

from roger_common.types import Action, ObjectSpec
from roger_experiments.compare import (
    RunResult,
    check_claims,
    check_completion,
    errors_markdown,
    read_cycles,
    report_markdown,
    sign_test_p,
    table2,
)
from roger_experiments.evaluation import (
    CycleRow,
    RunRecorder,
    RunScorer,
    counters_from_rows,
    object_under_window,
    rows_from_csv,
    score_cycles,
)

S, V, H, M = (int(a) for a in Action)


def obj(name: str, intensity: float = 99.0, weight: float = 1.0) -> ObjectSpec:
    return ObjectSpec(name=name, shape="box", position=(0.8, 0.0), size=0.2,
                      intensity=intensity, weight=weight)


def row(cycle, action, true, outcome, address=-1, roi=1) -> CycleRow:
    return CycleRow(cycle=cycle, state="000", action=action, reward=0.0, td_error=None,
                    roi=roi, true_object=true, outcome=outcome, address=address)


def test_same_category_identifications_are_correct_others_are_not():
    # a1 and a2 are one category (identical properties); b differs in weight.
    scorer = RunScorer({o.name: o for o in (obj("a1"), obj("a2"), obj("b", weight=0.5))})
    log = [row(1, S, "a1", "undetermined"), row(2, M, "a1", "stored", address=0),
           row(3, S, "a2", "identified"), row(4, M, "a2", "mapped", address=0),   # right
           row(5, S, "b", "identified"), row(6, M, "b", "mapped", address=0),     # wrong
           row(7, S, "b", "undetermined"), row(8, M, "b", "stored", address=1),   # right
           row(9, S, "a2", "undetermined"), row(10, M, "a2", "stored", address=2)]  # wrong
    for r in log:
        scorer.add(r)
    res = scorer.results()
    assert res["identification_precision"] == pytest.approx(1 / 2)
    assert res["novelty_precision"] == pytest.approx(2 / 3)
    assert res["objects_visited"] == 3 and res["objects_in_world"] == 3


def test_each_scored_mistake_is_kept_with_what_it_was_taken_for():
    # a1, a2 one category; b another; b stands at (1.2, 0.3), the a's at (0.8, 0).
    b = ObjectSpec(name="b", shape="box", position=(1.2, 0.3), size=0.2, intensity=99.0,
                   weight=0.5)
    scorer = RunScorer({o.name: o for o in (obj("a1"), obj("a2"), b)})

    def at(r: CycleRow, x: float, y: float) -> CycleRow:
        return CycleRow(**{**r.__dict__, "position": (x, y, 0.05)})

    log = [row(2, M, "a1", "stored", address=0),
           row(4, M, "a2", "mapped", address=0),            # right: no error
           row(6, M, "b", "mapped", address=0),             # b taken for a1
           row(8, M, "a2", "stored", address=1),            # a's category stored again
           row(10, M, None, "stored", address=2),           # no single object in view
           row(12, M, "b", "remapped", address=1),          # b taken for a2 (its store)
           at(row(13, S, None, "undetermined"), 1.18, 0.3),  # window near b, empty
           at(row(14, S, "a1", "lost"), -1.0, 0.0),          # lost: empty, far from all
           row(15, S, "a1", "identified")]                   # a visit: no error
    for r in log:
        scorer.add(r)
    got = [(e.cycle, e.kind, e.object, e.address, e.other) for e in scorer.errors]
    assert got == [(6, "wrong_identification", "b", 0, "a1"),
                   (8, "repeated_store", "a2", 1, "a1"),
                   (10, "store_of_nothing", "", 2, ""),
                   (12, "wrong_remap", "b", 1, "a2"),
                   (13, "empty_shift", "", -1, "b"),
                   (14, "empty_shift", "", -1, "a1")]
    assert scorer.errors[4].distance_m == pytest.approx(0.02, abs=1e-9)
    assert scorer.errors[5].distance_m == pytest.approx(1.8, abs=1e-9)
    # The errors are the precisions' complements, one for one.
    res = scorer.results()
    wrong_ids = sum(e.kind == "wrong_identification" for e in scorer.errors)
    assert res["identification_precision"] == pytest.approx(1 - wrong_ids / 2)
    wrong_stores = sum(e.kind in ("repeated_store", "store_of_nothing") for e in scorer.errors)
    assert res["novelty_precision"] == pytest.approx(1 - wrong_stores / 3)
    text = errors_markdown([RunResult("straightforward", 3, {}, [],
                                      [dict(zip(("cycle", "kind", "object", "address", "other",
                                                 "distance_m"), e.as_csv(), strict=True))
                                       for e in scorer.errors])])
    assert "straightforward, seed 3" in text
    assert "b **as** a1 x1" in text and "a2 (a1)" in text
    assert "2 empty shifts: 1 near an object (b)" in text


def test_a_finished_run_is_scored_again_from_its_files(tmp_path):
    objs = [obj("a1"), obj("a2"), obj("b", weight=0.5)]
    rec = RunRecorder(tmp_path, objs, {})
    log = [CycleRow(1, "000", S, 0.0, 0.25, 1, "a1", "undetermined", "000", -1,
                    (0.8, 0.01, 0.05), 1.5, True),
           row(2, M, "a1", "stored", address=0), row(3, M, "b", "mapped", address=0),
           CycleRow(4, "011", S, 0.0, None, 2, None, "undetermined", "000", -1,
                    (0.9, 0.0, 0.05), 2.5, False)]
    for r in log:
        rec.add(r)
    rec.counters = counters_from_rows(log)
    metrics = rec.close(1.0)
    rows = read_cycles(tmp_path / "cycles.csv")
    again = rows_from_csv(rows)
    assert [(r.cycle, r.action, r.true_object, r.outcome, r.address, r.converged)
            for r in again] == [(r.cycle, r.action, r.true_object, r.outcome, r.address,
                                 r.converged) for r in log]
    assert again[0].position == pytest.approx((0.8, 0.01, 0.05))
    assert again[0].td_error == pytest.approx(0.25) and again[1].position is None
    scorer = score_cycles(rows, objs)
    for key in ("identification_precision", "novelty_precision", "objects_visited"):
        assert scorer.results()[key] == metrics[key]
    # errors.csv is written with metrics.json and holds the scorer's errors.
    written = read_cycles(tmp_path / "errors.csv")
    assert [(e["cycle"], e["kind"], e["object"], e["other"]) for e in written] == [
        ("3", "wrong_identification", "b", "a1"), ("4", "empty_shift", "", "a1")]
    assert [e.as_csv() for e in scorer.errors] == [list(e.values()) for e in written]


def test_map_update_takes_the_object_last_seen_for_its_roi():
    scorer = RunScorer({"a": obj("a"), "b": obj("b", weight=0.5)})
    assert scorer.true_object_for(S, 4, "a") == "a"
    assert scorer.true_object_for(S, 5, "b") == "b"
    assert scorer.true_object_for(M, 4, None) == "a"
    assert scorer.true_object_for(M, 9, None) is None


def test_a_lost_cycle_shows_no_object_and_visits_nothing():
    # The forgotten entry's window is of an earlier frame: whatever this frame shows
    # there, no look happened.
    scorer = RunScorer({"a": obj("a"), "b": obj("b", weight=0.5)})
    assert scorer.true_object_for(S, 4, "a", "lost") is None
    scorer.add(row(1, S, None, "lost", roi=4))
    assert scorer.results()["objects_visited"] == 0
    assert scorer.true_object_for(M, 4, None) is None   # nothing remembered for roi 4


def labels_with(*boxes: tuple[int, int, int, int, int]) -> np.ndarray:
    img = np.full((40, 40), -1, np.int32)
    for idx, x0, y0, x1, y1 in boxes:
        img[y0:y1, x0:x1] = idx
    return img


def test_a_window_shows_an_object_only_when_the_object_fills_most_of_it():
    names = ("a", "b")
    # The object spans the window (a margin of a pixel or two): shown.
    assert object_under_window(labels_with((0, 10, 10, 20, 20)), names, (9, 9, 21, 21)) == "a"
    # A triangle covers half of its own box: its extent still fills the window.
    tri = np.full((40, 40), -1, np.int32)
    for r in range(10):
        tri[10 + r, 10:11 + r] = 1
    assert object_under_window(tri, names, (10, 10, 20, 20)) == "b"
    # Mostly ground, with an object in a corner: no object, no visit.
    assert object_under_window(labels_with((0, 10, 10, 14, 14)), names, (10, 10, 30, 30)) \
        is None
    # Two objects side by side, each half of the window: neither fills it.
    assert object_under_window(labels_with((0, 10, 10, 20, 30), (1, 20, 10, 30, 30)), names,
                               (10, 10, 30, 30)) is None
    assert object_under_window(labels_with(), names, (0, 0, 10, 10)) is None


def test_a_window_that_is_a_small_objects_own_box_shows_it():
    names = ("a", "b")
    # A far prism 2 x 4 px in a 4 x 4 window (its ROI, a pixel of halo each side): the
    # extent is half of the window, but the window is the object's own box.
    far = labels_with((0, 13, 12, 15, 16))
    assert object_under_window(far, names, (12, 12, 16, 16)) == "a"
    # Two pixels of halo are still its box; three are not (a window of mostly ground).
    assert object_under_window(far, names, (11, 10, 17, 18)) == "a"
    assert object_under_window(far, names, (10, 12, 16, 16)) is None
    # Part of the object outside the window: not its box.
    assert object_under_window(far, names, (12, 12, 16, 14)) is None
    # Another object's pixel in the window: a window between two objects shows neither.
    near = far.copy()
    near[12, 15] = 1
    assert object_under_window(near, names, (12, 12, 16, 16)) is None


def test_no_identification_gives_no_precision_not_zero():
    scorer = RunScorer({"a": obj("a")})
    scorer.add(row(1, S, "a", "undetermined"))
    assert scorer.results()["identification_precision"] is None


def test_recorder_writes_csv_per_row_and_counters_match_the_log(tmp_path):
    rec = RunRecorder(tmp_path, [obj("a")], {"policy": "p"}, memory_file=tmp_path / "m.pt")
    rows = [row(1, S, "a", "undetermined"), row(2, V, "a", "undetermined"),
            row(3, H, "a", "new"), row(4, M, "a", "stored", address=0)]
    for r in rows[:2]:
        rec.add(r)
    assert len((tmp_path / "cycles.csv").read_text().splitlines()) == 3  # flushed already
    for r in rows[2:]:
        rec.add(r)
    rec.counters = counters_from_rows(rows)
    metrics = rec.close(1.0)
    assert metrics["cycles"] == 4 and metrics["new_objects"] == 1 and metrics["improvements"] == 2
    assert json.loads((tmp_path / "metrics.json").read_text()) == metrics
    # The evaluation's sidecar lets a later run that loads the memory score it.
    rec2 = RunRecorder(tmp_path / "second", [obj("a")], {}, memory_file=tmp_path / "m.pt")
    rec2.add(row(1, S, "a", "identified"))
    rec2.add(row(2, M, "a", "mapped", address=0))
    assert rec2.scorer.results()["identification_precision"] == 1.0


def test_sign_test_and_claims():
    assert sign_test_p(5, 0) == pytest.approx(2 / 32)
    assert sign_test_p(0, 0) == 1.0
    base = {"attention_shifts": 10, "improvements": 10, "positive_identifications": 5,
            "new_objects": 5, "map_updates": 10, "objects_visited": 4,
            "identification_precision": 1.0, "novelty_precision": 1.0, "wall_seconds": 1.0,
            "cycles": 30}
    results = []
    for seed in range(5):
        q = dict(base, attention_shifts=12 + seed, improvements=8)
        results += [RunResult("qlearning", seed, q, []), RunResult("straightforward", seed,
                                                                   dict(base), [])]
    claims = {c["column"]: c for c in check_claims(results)}
    assert claims["attention_shifts"]["verdict"] == "holds"
    assert claims["attention_shifts"]["holds_in"] == 5
    assert claims["improvements"]["verdict"] == "holds"
    assert claims["map_updates"]["verdict"] == "no difference"
    t = table2(results)
    assert t["qlearning"]["attention_shifts"]["mean"] == pytest.approx(14.0)
    assert t["straightforward"]["attention_shifts"]["sd"] == 0.0


def test_the_sixth_claim_counts_runs_that_visited_everything_after_the_robots_rule():
    def run(policy, seed, visited, complete=True):
        return RunResult(policy, seed, {"cycles": 100 + seed, "complete": complete,
                                        "objects_visited": visited, "objects_in_world": 4,
                                        "every_object_visited": visited == 4}, [])
    all_seen = [run(p, s, 4) for p in ("qlearning", "straightforward") for s in (0, 1)]
    c = check_completion(all_seen)
    assert (c["verdict"], c["every_object_visited"], c["runs"]) == ("holds", 4, 4)
    c = check_completion(all_seen[:3] + [run("straightforward", 1, 3)])
    assert c["verdict"] == "holds in some runs"
    assert c["per_policy"]["straightforward"]["objects_visited"] == [4, 3]
    none = check_completion([run("qlearning", 0, 3, complete=False)])
    assert none["verdict"] == "does not hold" and none["complete"] == 0
    base = {"attention_shifts": 1, "improvements": 1, "positive_identifications": 1,
            "new_objects": 1, "remaps": 0, "map_updates": 2, "objects_visited": 4,
            "identification_precision": 1.0, "novelty_precision": 1.0,
            "remap_precision": None, "wall_seconds": 1.0, "cycles": 4}
    results = [RunResult(p, 0, base, []) for p in ("qlearning", "straightforward")]
    report = report_markdown(table2(results), check_claims(results), "w.yaml", "", c)
    section = report.split("## The paper's claims")[1]
    claims = [ln for ln in section.splitlines() if ln.startswith("| Q-learning") or
              ln.startswith("| Every object")]
    assert len(claims) == 6 and claims[-1].startswith("| Every object is visited")
