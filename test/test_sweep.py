"""roger sweep and Table 2 as one module: the statistics, the spec, the step-size
schedules, resumption after a failure, a timeout or a kill, how much the training draws
agree, and the embedded Ray's ports and leftovers (issue 37).

The Ray tests run a tiny sweep (2 worlds x 1 seed x 2 policies, 6 cycles) through the
real ``roger sweep`` command; the others run in this process without Ray (the timeout
test runs ``RayRunner`` against a stand-in for Ray of its own).
"""

from __future__ import annotations

import csv
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
import types
from dataclasses import asdict
from pathlib import Path

import pytest
import yaml
from conftest import WORLDS, alive

from roger_attention.config import QLearningConfig
from roger_attention.fsm import STATES
from roger_attention.qlearning import QTable
from roger_common.errors import ConfigError
from roger_common.types import Action
from roger_experiments import ray_runner, sweep
from roger_experiments.ray_runner import LOOPBACK_ENV, RayRunner
from roger_experiments.runners import Job, RunSpec, SequentialRunner, run_in_process
from roger_experiments.table2 import paired_test, wilcoxon_signed_rank
from roger_experiments.train import TrainDraw

TINY = {"worlds": [str(WORLDS / "table1.yaml"),
                   {"recipe": "default", "n_categories": 3, "copies": 2, "seeds": [5]}],
        "seeds": [0], "policies": ["qlearning", "straightforward"], "features": ["paper"],
        "draws": 0, "cycles": 6, "mode": "in_process"}


# --- Statistics ---------------------------------------------------------------------------

def test_wilcoxon_is_exact_with_and_without_ties():
    # Five positive differences: the one most extreme arrangement of 2^5 on each side.
    assert wilcoxon_signed_rank([1, 2, 3, 4, 5])["p"] == pytest.approx(2 / 32)
    # Zeros are dropped; the rank-biserial correlation is +1 when every pair agrees.
    w = wilcoxon_signed_rank([0, 1, 2, 3, 4, 5])
    assert w["n"] == 5 and w["rank_biserial"] == 1.0
    # Symmetric differences: no effect, p = 1.
    assert wilcoxon_signed_rank([-2, -1, 1, 2])["p"] == pytest.approx(1.0)
    # Ties (mean ranks 1.5, 1.5, 3): W+ = 4.5 of 6. Exact null: W+ in {0, 1.5, 1.5, 3, 3,
    # 4.5, 4.5, 6}; P(W+ >= 4.5) = 3/8, two-sided 0.75.
    assert wilcoxon_signed_rank([1, -1, 2])["p"] == pytest.approx(0.75)
    assert wilcoxon_signed_rank([])["p"] == 1.0


def test_paired_test_verdicts_follow_the_claimed_direction():
    more = {f"w{k}": [1.0 + k % 3, 2.0] for k in range(10)}
    assert paired_test(more, +1)["verdict"] == "holds"
    assert paired_test(more, -1)["verdict"] == "contradicted"
    mixed = {f"w{k}": [(-1.0) ** k] for k in range(10)}
    judged = paired_test(mixed, +1)
    assert judged["verdict"] == "not shown" and judged["pairs"] == 10
    lo, hi = judged["ci95"]
    assert lo < 0 < hi


# --- The spec -------------------------------------------------------------------------------

def test_spec_keys_recipes_and_errors(tmp_path):
    spec = sweep.parse_spec({**TINY, "cycles": [6, "until-complete"], "draws": 2,
                             "worlds": [*TINY["worlds"],
                                        {"recipe": "shape_twins", "n_categories": 3,
                                         "copies": 2, "seeds": {"start": 7, "count": 2}}]},
                            "tiny.yaml", tmp_path)
    assert [w.name for w in spec.worlds] == ["table1", "random_3x2_5", "random_3x2_7_twins",
                                             "random_3x2_8_twins"]
    assert spec.cycles == (6, None)
    cells = sweep.cells(spec, "v1")
    # Q-learning once per draw, straightforward once: 4 worlds x 2 budgets x (2 + 1).
    assert len(cells) == 4 * 2 * 3 and len({c.key for c in cells}) == len(cells)
    assert {c.key for c in cells} != {c.key for c in sweep.cells(spec, "v2")}
    for bad, words in (({"mode": "cluster"}, "mode"), ({"colour": 1}, "unknown key"),
                       ({"worlds": [{"recipe": "spiral"}]}, "recipe"),
                       ({"cycles": "forever"}, "cycles")):
        with pytest.raises(ConfigError, match=words):
            sweep.parse_spec({**TINY, **bad}, "bad.yaml", tmp_path)


def test_a_training_world_that_is_an_evaluation_world_is_refused(tmp_path):
    # Draw 1 trains on random worlds of seeds 5 and 6: the evaluation's random_8x3_5 too.
    spec = sweep.parse_spec({**TINY, "draws": 1, "worlds": [
        {"recipe": "default", "n_categories": 8, "copies": 3, "seeds": [5],
         "size_range": [0.08, 0.14]}],
        "training": {"worlds": 2, "seeds": 1, "cycles": 6, "world_seed0": 5}},
        "t.yaml", tmp_path)
    with pytest.raises(ConfigError, match="is the evaluation world"):
        sweep.check_disjoint(spec)


def test_shipped_claims_spec_parses():
    spec = sweep.load_spec(Path(__file__).resolve().parents[1] / "sweeps" / "claims.yaml")
    assert len(spec.worlds) >= 20 and spec.draws == 3 and len(spec.seeds) == 2
    assert spec.alpha_schedules == ("constant",)
    sweep.check_disjoint(spec)


def test_every_shipped_spec_parses_and_the_schedules_spec_reuses_the_claims_cells():
    folder = Path(__file__).resolve().parents[1] / "sweeps"
    specs = {path.name: sweep.load_spec(path) for path in sorted(folder.glob("*.yaml"))}
    assert {"claims.yaml", "schedules.yaml"} <= set(specs)
    for spec in specs.values():
        sweep.check_disjoint(spec)
    assert specs["schedules.yaml"].alpha_schedules == ("constant", "visits")
    claims = {c.key for c in sweep.cells(specs["claims.yaml"], "v")}
    both = sweep.cells(specs["schedules.yaml"], "v")
    visits = [c for c in both if c.alpha_schedule == "visits"]
    others = {c.key for c in both if c.alpha_schedule != "visits"}
    # Its constant and straightforward cells are the claims sweep's (run into one folder,
    # only the visits cells run); the visits cells are new.
    assert visits and others and others <= claims
    assert not {c.key for c in visits} & claims
    # claims-visits.yaml: the paper mode's half of claims.yaml plus its visits cells, of
    # which schedules.yaml's are some.
    paper = sweep.cells(specs["claims-visits.yaml"], "v")
    assert {c.key for c in paper if c.alpha_schedule != "visits"} <= claims
    assert {c.key for c in visits if c.features == "paper"} <= {c.key for c in paper}
    assert len(paper) == 280


def _old_key(data: object, version: str) -> str:
    """The cell and training key as sweep.digest made it before alpha_schedules existed,
    written out here so that a change of the formula shows."""
    text = json.dumps([data, version], sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def test_alpha_schedules_add_cells_and_leave_the_old_keys_alone(tmp_path):
    base = {**TINY, "draws": 2, "cycles": [6, "until-complete"]}
    old = sweep.parse_spec(base, "tiny.yaml", tmp_path)
    assert old.alpha_schedules == ("constant",)
    old_cells = sweep.cells(old, "v1")
    # The same cells and keys with the default said out loud, and the keys are the ones
    # made before the key existed: a resumed old sweep finds every cell it ran.
    said = sweep.cells(sweep.parse_spec({**base, "alpha_schedules": ["constant"]},
                                        "tiny.yaml", tmp_path), "v1")
    assert [(c.key, c.train_key) for c in said] == [(c.key, c.train_key) for c in old_cells]
    for c in old_cells:
        tkey = None
        if c.draw:
            tkey = _old_key({"train": asdict(TrainDraw(
                c.draw, c.features, old.training.draw(c.draw, c.features).worlds,
                (0, 1), 204))}, "v1")
        assert c.train_key == tkey
        assert c.key == _old_key({"world": c.world.name, "world_digest": c.world.digest(),
                                  "policy": c.policy, "seed": c.seed,
                                  "features": c.features, "cycles": c.cycles,
                                  "draw": c.draw, "train": tkey, "mode": "in_process",
                                  "stable_cycles": 40}, "v1")
        assert c.alpha_schedule == ("constant" if c.policy == "qlearning" else "")
    # Both schedules: the old cells plus the Q-learning cells again with "visits", each
    # draw trained once per schedule under a key of its own.
    both = sweep.cells(sweep.parse_spec({**base, "alpha_schedules": ["constant", "visits"]},
                                        "tiny.yaml", tmp_path), "v1")
    new = [c for c in both if c.key not in {o.key for o in old_cells}]
    assert {c.key for c in old_cells} < {c.key for c in both}
    assert len(new) == sum(c.policy == "qlearning" for c in old_cells)
    assert {(c.policy, c.alpha_schedule) for c in new} == {("qlearning", "visits")}
    by_draw = {(c.features, c.draw, c.alpha_schedule): c.train_key for c in both if c.draw}
    for draw in (1, 2):
        assert by_draw[("paper", draw, "constant")] != by_draw[("paper", draw, "visits")]
    assert len({c.key for c in both}) == len(both)
    row = new[0].row()
    assert row["alpha_schedule"] == "visits" and list(row)[-1] == "alpha_schedule"
    # Draw 0 (learning online in the run): a cell per schedule too.
    online = sweep.cells(sweep.parse_spec({**TINY, "alpha_schedules": ["constant", "visits"]},
                                          "tiny.yaml", tmp_path), "v1")
    assert sorted(c.alpha_schedule for c in online) == ["", "", "constant", "constant",
                                                        "visits", "visits"]
    for bad, words in ((["annealed"], "bad.yaml: alpha_schedules: 'annealed' is not one of"),
                       (["visits", "visits"], "bad.yaml: alpha_schedules: a list of distinct"),
                       ([], "bad.yaml: alpha_schedules")):
        with pytest.raises(ConfigError, match=words):
            sweep.parse_spec({**TINY, "alpha_schedules": bad}, "bad.yaml", tmp_path)
    assert sweep.parse_spec({**TINY, "alpha_schedules": "visits"}, "t.yaml",
                            tmp_path).alpha_schedules == ("visits",)


# --- Failures and resumption (in process, no Ray) -------------------------------------------

def test_failing_cells_are_recorded_and_only_unfinished_cells_run_again(tmp_path):
    spec = sweep.parse_spec({**TINY, "worlds": TINY["worlds"][1:]}, "tiny.yaml", tmp_path)
    out = tmp_path / "sweep"
    calls: list[str] = []

    def flaky(run, folder):
        calls.append(f"{run.policy}@{Path(run.world).stem}")
        if run.policy == "straightforward":
            raise RuntimeError("a run that fails")
        return run_in_process(run, folder)

    def runner(run_fn):
        inner = SequentialRunner(run_fn, keep_going=True)

        def go(jobs: list[Job]):
            for job, result in inner(jobs):
                if not isinstance(result, Exception):
                    # What RayRunner does: the run's folder gets the caller's files too.
                    for name, data in job.extra.items():
                        (job.out / name).write_bytes(data)
                yield job, result
        return go

    first = sweep.run_sweep(spec, out, runner(flaky), runner(flaky), "v1", progress=False)
    assert first["done"] == 1 and first["failed"] == 1 and len(calls) == 2
    rows = (out / "runs.csv").read_text().splitlines()
    assert len(rows) == 1 + 2 and ",failed," in rows[2] and "a run that fails" in rows[2]
    failed = sorted((out / "failed").iterdir())
    assert len(failed) == 1
    assert "a run that fails" in (failed[0] / "error.txt").read_text()
    # A driver killed while a cell was being written leaves a folder without cell.json
    # (or a scratch folder): that cell is not finished.
    done = sorted(p for p in (out / "cells").iterdir())
    (done[0] / "cell.json").unlink()
    again: list[str] = []

    def counting(run, folder):
        again.append(run.policy)
        return run_in_process(run, folder)
    second = sweep.run_sweep(spec, out, runner(counting), runner(counting), "v1",
                             progress=False)
    assert second["done"] == 2 and second["failed"] == 0
    assert sorted(again) == ["qlearning", "straightforward"]
    assert not (out / "failed").exists() or not any((out / "failed").iterdir())
    header, *lines = (out / "runs.csv").read_text().splitlines()
    columns = header.split(",")
    for key in ("key", "world_name", "seed", "policy", "features", "draw", "budget",
                "status", "attention_shifts", "every_object_visited", "wall_seconds"):
        assert key in columns, key
    assert all(",done," in line for line in lines)
    for name in ("report.md", "table2.json", "claims.json", "fig_attention_shifts.png"):
        assert (out / name).stat().st_size > 0, name
    # A third pass finds everything on disk and runs nothing.
    again.clear()
    third = sweep.run_sweep(spec, out, runner(counting), runner(counting), "v1",
                            progress=False)
    assert again == [] and third["done"] == 2


def test_report_only_reports_the_runs_on_disk_and_runs_nothing(tmp_path, monkeypatch,
                                                                capsys):
    """``roger sweep --report-only``: a change to the report code changes the code version
    and so every key; the runs already in DIR are reported as they are, none is run."""
    from roger_bringup import cli

    data = {**TINY, "worlds": TINY["worlds"][1:]}
    spec = sweep.parse_spec(data, "tiny.yaml", tmp_path)
    out = tmp_path / "sweep"
    sweep.run_sweep(spec, out, _sequential(run_in_process), _trainer, "v1", progress=False)
    spec_file = tmp_path / "tiny.yaml"
    spec_file.write_text(yaml.safe_dump(data))
    before = _runs(out)
    (out / "report.md").unlink()
    (out / "runs.csv").unlink()

    def no_ray(*args, **kwargs):
        raise AssertionError("--report-only started Ray")
    monkeypatch.setattr(ray_runner, "start_ray", no_ray)
    assert sweep.versions_on_disk(out) == ["v1"]
    with pytest.raises(SystemExit) as code:
        cli.main(["sweep", str(spec_file), "--out", str(out), "--report-only"])
    assert code.value.code == 0
    assert _runs(out) == before and all(r["status"] == "done" for r in before)
    assert "Code version v1." in (out / "report.md").read_text()
    assert "reporting the runs of code version v1" in capsys.readouterr().err
    # Another version's runs beside them: which to report must be named.
    other = out / "cells" / "0000000000000000"
    other.mkdir()
    (other / "cell.json").write_text(json.dumps({"code_version": "v0"}))
    with pytest.raises(SystemExit) as code:
        cli.main(["sweep", str(spec_file), "--out", str(out), "--report-only"])
    assert code.value.code == 2
    assert "code versions v0, v1; name one with --code-version" in capsys.readouterr().err
    with pytest.raises(SystemExit) as code:
        cli.main(["sweep", str(spec_file), "--out", str(out), "--report-only",
                  "--code-version", "v0"])
    assert code.value.code == 0
    assert all(r["status"] == "not run" for r in _runs(out))


def _sequential(run_fn):
    """A runner of jobs one after another in this process that, as RayRunner, puts the
    caller's files (cell.json) into each finished job's folder."""
    inner = SequentialRunner(run_fn, keep_going=True)

    def go(jobs):
        for job, result in inner(jobs):
            if not isinstance(result, Exception):
                for name, data in job.extra.items():
                    (job.out / name).write_bytes(data)
            yield job, result
    return go


def _trainer(jobs):
    """The training draws one after another in this process (``roger sweep``'s task)."""
    for job in jobs:
        metrics = sweep.train_scheduled(job.spec, job.out)
        for name, data in job.extra.items():
            (job.out / name).write_bytes(data)
        yield job, metrics


def _runs(out: Path) -> list[dict[str, str]]:
    with open(out / "runs.csv", newline="") as fh:
        return list(csv.DictReader(fh))


def test_each_schedule_trains_its_own_tables_and_is_reported_apart(tmp_path):
    spec = sweep.parse_spec({**TINY, "worlds": TINY["worlds"][1:], "draws": 1,
                             "alpha_schedules": ["constant", "visits"],
                             "training": {"worlds": 1, "seeds": 1, "cycles": 6}},
                            "tiny.yaml", tmp_path)
    out = tmp_path / "sweep"
    result = sweep.run_sweep(spec, out, _sequential(run_in_process), _trainer, "v1",
                             progress=False)
    assert result["done"] == 3 and result["failed"] == 0
    # Each draw's table learnt with its schedule, and each Q-learning cell ran its own.
    cells = {(c.policy, c.alpha_schedule): c for c in sweep.cells(spec, "v1", out / "worlds")}
    for schedule in ("constant", "visits"):
        c = cells[("qlearning", schedule)]
        table = json.loads((out / "train" / c.train_key / "qtable.json").read_text())
        assert table["alpha_schedule"] == schedule
        assert json.loads((out / "train" / c.train_key / "train.json").read_text())[
            "alpha_schedule"] == schedule
        cell = json.loads((out / "cells" / c.key / "cell.json").read_text())
        assert cell["alpha_schedule"] == schedule and cell["train_key"] == c.train_key
    assert {(r["policy"], r["alpha_schedule"], r["status"]) for r in _runs(out)} == {
        ("qlearning", "constant", "done"), ("qlearning", "visits", "done"),
        ("straightforward", "", "done")}
    assert {(e["policy"], e["alpha_schedule"]) for e in result["table2"]} == {
        ("qlearning", "constant"), ("qlearning", "visits"), ("straightforward", "")}
    claims = json.loads((out / "claims.json").read_text())["claims"]
    assert {c["alpha_schedule"] for c in claims} == {"constant", "visits"}
    assert all(c["pairs"] == 1 for c in claims)  # each schedule against the one baseline
    agreement = json.loads((out / "draws.json").read_text())["agreement"]
    assert [(a["features"], a["alpha_schedule"], a["trained"], a["share"])
            for a in agreement] == [("paper", "constant", 1, None),
                                    ("paper", "visits", 1, None)]
    report = (out / "report.md").read_text()
    assert "| paper | visits | 6 |" in report and "step size visits" in report
    # A table whose schedule is not its draw's (here edited by hand) is never run as the
    # draw's: its cells fail, saying why.
    c = cells[("qlearning", "constant")]
    path = out / "train" / c.train_key / "qtable.json"
    path.write_text(json.dumps({**json.loads(path.read_text()), "alpha_schedule": "visits"}))
    shutil.rmtree(out / "cells" / c.key)
    again = sweep.run_sweep(spec, out, _sequential(run_in_process), _trainer, "v1",
                            progress=False)
    assert again["failed"] == 1 and not (out / "cells" / c.key).exists()
    row = next(r for r in _runs(out) if r["key"] == c.key)
    assert row["status"] == "failed" and "learnt with step size visits" in row["error"]


def test_a_run_that_learns_online_starts_from_a_table_of_its_schedule(tmp_path):
    spec = sweep.parse_spec({**TINY, "worlds": TINY["worlds"][1:], "policies": ["qlearning"],
                             "alpha_schedules": ["visits"]}, "tiny.yaml", tmp_path)
    out = tmp_path / "sweep"
    assert sweep.run_sweep(spec, out, _sequential(run_in_process), _trainer, "v1",
                           progress=False)["done"] == 1
    (cell,) = sweep.cells(spec, "v1")
    table = json.loads((out / "cells" / cell.key / "qtable.json").read_text())
    assert table["alpha_schedule"] == "visits" and table["updates"] > 0


class _Clock:
    """ray_runner's ``time`` in the timeout test: a monotonic clock that moves only when
    the stand-in Ray lets a wait's timeout pass."""

    def __init__(self) -> None:
        self.now = 0.0

    def monotonic(self) -> float:
        return self.now

    def time(self) -> float:
        return time.time()


class _Ref:
    def __init__(self) -> None:
        self.ready = False
        self.value: object = None


class _FakeRay(types.ModuleType):
    """As much of Ray as RayRunner uses, in this process: a task runs when it is
    submitted, except one that ``hangs`` (a run that never finishes); ``wait`` with
    nothing ready lets its timeout pass on the clock."""

    def __init__(self, clock: _Clock, hangs) -> None:
        super().__init__("ray")
        self.clock, self.hangs = clock, hangs
        self.cancelled: list[_Ref] = []
        self.waits = 0

    def is_initialized(self) -> bool:
        return False

    def remote(self, **_options):
        def wrap(fn):
            def submit(*args):
                ref = _Ref()
                if not self.hangs(args[1]):
                    ref.value, ref.ready = fn(*args), True
                return ref
            return types.SimpleNamespace(remote=submit)
        return wrap

    def wait(self, refs, num_returns, timeout):
        self.waits += 1
        assert self.waits < 1000, "the runner never gave up on the run that hangs"
        ready = [r for r in refs if r.ready][:num_returns]
        if not ready:
            self.clock.now += timeout
        return ready, [r for r in refs if r not in ready]

    def get(self, ref):
        assert ref.ready, "a result asked of a run that never finished"
        return ref.value

    def cancel(self, ref, force=False):
        self.cancelled.append(ref)


def test_a_cell_past_its_timeout_fails_with_its_error_and_the_others_finish(
        tmp_path, monkeypatch):
    # One slot (workers: 1): the cells after the one that hangs run only if the timeout
    # takes it off.
    spec = sweep.parse_spec({**TINY, "worlds": TINY["worlds"][1:], "seeds": [0, 1],
                             "timeout_s": 30}, "tiny.yaml", tmp_path)
    clock = _Clock()
    fake = _FakeRay(clock, lambda run: run.policy == "straightforward" and run.seed == 0)
    monkeypatch.setitem(sys.modules, "ray", fake)
    monkeypatch.setattr(ray_runner, "time", clock)
    runner = RayRunner(run_in_process, workers=1, keep_going=True, timeout_s=spec.timeout_s)
    out = tmp_path / "sweep"
    result = sweep.run_sweep(spec, out, runner, _trainer, "v1", progress=False)
    assert result["done"] == 3 and result["failed"] == 1
    assert len(fake.cancelled) == 1 and not fake.cancelled[0].ready
    rows = _runs(out)
    hung = [r for r in rows if r["status"] == "failed"]
    assert [(r["policy"], r["seed"]) for r in hung] == [("straightforward", "0")]
    assert hung[0]["error"] == "timed out after 30 s"
    assert "timed out after 30 s" in (out / "failed" / hung[0]["key"] / "error.txt").read_text()
    assert json.loads((out / "failed" / hung[0]["key"] / "spec.json").read_text())[
        "key"] == hung[0]["key"]
    assert sorted((r["policy"], r["seed"]) for r in rows if r["status"] == "done") == [
        ("qlearning", "0"), ("qlearning", "1"), ("straightforward", "1")]
    assert "timed out after 30 s" in (out / "report.md").read_text()
    # The next sweep tries the timed-out cell again (and only it).
    fake.hangs = lambda run: False
    again = sweep.run_sweep(spec, out, runner, _trainer, "v1", progress=False)
    assert again["done"] == 4 and again["failed"] == 0
    assert not (out / "failed" / hung[0]["key"]).exists()


def test_draw_agreement_counts_the_states_whose_greedy_action_and_ranking_every_draw_shares(
        tmp_path):
    spec = sweep.parse_spec({**TINY, "worlds": TINY["worlds"][1:], "draws": 3,
                             "alpha_schedules": ["constant", "visits"]}, "tiny.yaml",
                            tmp_path)
    out = tmp_path / "sweep"
    all_cells = sweep.cells(spec, "v1", out / "worlds")
    undetermined, mapped, identified = STATES[0], STATES[1], STATES[2]
    assert (undetermined.bits, mapped.bits, identified.bits) == ("000", "001", "010")
    for c in all_cells:
        if not c.draw or c.alpha_schedule != "constant":
            continue  # the visits draws: never trained (nothing to compare)
        table = QTable(QLearningConfig())
        # Draws 1 and 2 look twice in state 000, draw 3 touches; all map in 010; all look
        # in 001, where draw 2's second choice is a touch (the others' are tied).
        best = Action.HAPTIC_IMPROVEMENT if c.draw == 3 else Action.VISUAL_IMPROVEMENT
        table.q[undetermined.index, int(best)] = 0.5
        table.q[identified.index, int(Action.MAP_UPDATE)] = 0.8
        table.q[mapped.index, int(Action.VISUAL_IMPROVEMENT)] = 0.4
        if c.draw == 2:
            table.q[mapped.index, int(Action.HAPTIC_IMPROVEMENT)] = 0.3
        folder = out / "train" / c.train_key
        folder.mkdir(parents=True, exist_ok=True)
        table.save(folder / "qtable.json")
        (folder / "cell.json").write_text("{}")
    sweep.report(spec, all_cells, out, {})
    constant, visits = json.loads((out / "draws.json").read_text())["agreement"]
    assert (constant["alpha_schedule"], constant["draws"], constant["trained"]) == (
        "constant", 3, 3)
    assert constant["states_agreeing"] == 5 and constant["share"] == pytest.approx(5 / 6)
    per_state = {s["state"]: s for s in constant["per_state"]}
    assert per_state["000"]["greedy"] == {"1": ["visual_improvement"],
                                          "2": ["visual_improvement"],
                                          "3": ["haptic_improvement"]}
    assert not per_state["000"]["agree"]
    assert per_state["010"]["agree"] and per_state["010"]["greedy"]["3"] == ["map_update"]
    assert per_state["010"]["ranked_alike"]
    # Same greedy action in 001, but not the same robot: draw 2 touches next.
    assert per_state["001"]["agree"]
    assert per_state["001"]["ranking"]["2"] == [["visual_improvement"],
                                                ["haptic_improvement"], ["attention_shift"]]
    assert per_state["001"]["ranking"]["1"] == [["visual_improvement"],
                                                ["attention_shift", "haptic_improvement"]]
    assert not per_state["001"]["ranked_alike"]
    assert constant["states_ranked_alike"] == 4
    # What ranks below the shift is never taken (the shift ends the focus): left out.
    table = QTable(QLearningConfig())
    table.q[undetermined.index, int(Action.ATTENTION_SHIFT)] = 0.2
    table.q[undetermined.index, int(Action.HAPTIC_IMPROVEMENT)] = 0.1
    assert sweep.ranking(table, undetermined) == [["attention_shift"]]
    assert (visits["trained"], visits["share"], visits["states_agreeing"]) == (0, None, None)
    report = (out / "report.md").read_text()
    assert "## Do the training draws agree?" in report
    assert "5 of 6 states (83%) agree in all 3 trained draws on the greedy action, 4 on " \
           "the ranking" in report
    assert "| paper | constant | 000 | visual improvement > " in report
    assert "| no | no |" in report and "| yes | no |" in report


# --- The embedded Ray: ports, results, leftovers --------------------------------------------

def _listening(pids: set[int]) -> set[tuple[str, str]]:
    """(process name, local address) of every listening TCP socket of ``pids``."""
    inodes: dict[str, int] = {}
    for pid in pids:
        try:
            for fd in Path(f"/proc/{pid}/fd").iterdir():
                link = os.readlink(fd)
                if link.startswith("socket:["):
                    inodes[link[8:-1]] = pid
        except OSError:
            continue
    found = set()
    for table, v6 in (("/proc/net/tcp", False), ("/proc/net/tcp6", True)):
        for line in Path(table).read_text().splitlines()[1:]:
            parts = line.split()
            if parts[3] != "0A" or parts[9] not in inodes:  # 0A: LISTEN
                continue
            host = parts[1].split(":")[0]
            if v6:
                addr = ("::1" if host == "0" * 31 + "1" else "::" if host == "0" * 32 else
                        "127.0.0.1" if host.endswith("0100007F") and
                        host.startswith("0000000000000000FFFF0000") else f"[{host}]")
            else:
                addr = ".".join(str(int(host[i:i + 2], 16)) for i in (6, 4, 2, 0))
            try:
                name = Path(f"/proc/{inodes[parts[9]]}/comm").read_text().strip()
            except OSError:
                name = "?"
            found.add((name, addr))
    return found


def _ray_pids(marker: str) -> set[int]:
    """Processes of one Ray instance: its temp folder in their command line, or (Ray's
    agents retitle themselves "ray::DashboardAgent" and outlive their raylet for a minute)
    a file open under it."""
    pids = set()
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                if marker in (d / "cmdline").read_bytes().decode(errors="replace"):
                    pids.add(int(d.name))
                    continue
                for fd in (d / "fd").iterdir():
                    if os.readlink(fd).startswith(marker):
                        pids.add(int(d.name))
                        break
            except OSError:
                continue
    return pids


@pytest.fixture
def ray_tmp():
    """Ray's temp folder for one test (short: Ray's socket paths live in it); whatever a
    failed test left running from it is stopped afterwards, and the folder removed."""
    path = Path(tempfile.mkdtemp(prefix="rr", dir="/tmp"))
    yield path
    _stop(_ray_pids(str(path)))
    shutil.rmtree(path, ignore_errors=True)


def test_embedded_graph_sweep_loopback_only_side_by_side_and_nothing_left(no_leaks, ray_tmp,
                                                                          tmp_path):
    # Two graph cells at once on the embedded Ray (2 workers), each on a ROS domain of its
    # own; every port the sweep's processes listen on is loopback; nothing is left after.
    shm_before = set(os.listdir("/dev/shm"))
    spec_file = tmp_path / "graph.yaml"
    spec_file.write_text(yaml.safe_dump({**TINY, "worlds": [str(WORLDS / "table1.yaml")],
                                         "mode": "graph"}))
    out = tmp_path / "sweep"
    env = {**os.environ, "RAY_TMPDIR": str(ray_tmp)}
    env.pop("RAY_ADDRESS", None)
    env.pop(LOOPBACK_ENV, None)  # the sweep's own default, not the caller's
    proc = subprocess.Popen([sys.executable, "-m", "roger_bringup.cli", "sweep",
                             str(spec_file), "--out", str(out), "--workers", "2", "--quiet"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env=env)
    seen: set[tuple[str, str]] = set()
    dashboards: dict[int, str] = {}  # pid: command line of Ray's dashboard process
    dashboard_ports: set[tuple[str, str]] = set()
    try:
        while proc.poll() is None:
            pids = _ray_pids(str(ray_tmp))
            seen |= _listening(pids | {proc.pid})
            for pid in pids:
                try:
                    cmd = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ")
                except OSError:
                    continue
                if b"ray/dashboard/dashboard.py" in cmd:
                    dashboards[pid] = cmd.decode(errors="replace")
            dashboard_ports |= _listening(set(dashboards))
            time.sleep(0.2)
        output = proc.stdout.read() if proc.stdout else ""
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait()
        if proc.stdout:
            proc.stdout.close()
    assert proc.returncode == 0, output[-3000:]
    names = {name for name, _ in seen}
    assert {"gcs_server", "raylet"} <= names, seen
    exposed = sorted((n, a) for n, a in seen if a not in ("127.0.0.1", "::1"))
    assert not exposed, f"listening beyond loopback: {exposed}"
    # The dashboard is off: Ray 2.60 still starts its head process for usage statistics
    # (`--minimal --modules-to-load=UsageStatsHead --disable-frontend`), which serves no
    # page and listens on no port.
    assert not dashboard_ports, dashboard_ports
    assert all("--disable-frontend" in cmd for cmd in dashboards.values()), dashboards
    # Every Ray process is gone, and Ray left nothing in /dev/shm.
    left = _ray_pids(str(ray_tmp))
    for _ in range(100):
        if not left:
            break
        time.sleep(0.1)
        left = _ray_pids(str(ray_tmp))
    assert not left, f"Ray processes left: {sorted(left)}"
    assert not (set(os.listdir("/dev/shm")) - shm_before - _roger_shm()), \
        set(os.listdir("/dev/shm")) - shm_before
    # Each cell has its own complete cycles.csv, equal to the same cell run alone (in
    # process: test_graph_matches_core holds the graph to the core loop row for row).
    here = tmp_path / "here"
    rows = {json.loads((c / "cell.json").read_text())["key"]: c
            for c in (out / "cells").iterdir()}
    assert len(rows) == 2
    domains = {json.loads((c / "metrics.json").read_text())["domain_id"] for c in rows.values()}
    assert len(domains) == 2, domains
    for key, folder in rows.items():
        cell = json.loads((folder / "cell.json").read_text())
        assert cell["key"] == key and folder.name == key
        run = RunSpec(cell["world"], Path(cell["world"]).read_text(), cell["policy"],
                            cell["seed"], cell["budget"], cell["features"])
        run_in_process(run, here / key)
        assert (here / key / "cycles.csv").read_text() == (folder / "cycles.csv").read_text()
        metrics = json.loads((folder / "metrics.json").read_text())
        assert metrics["cycles"] == 6 and metrics["policy"] == cell["policy"]


def _roger_shm() -> set[str]:
    """Fast DDS files another graph on the machine may have made meanwhile (not Ray's)."""
    return {f for f in os.listdir("/dev/shm") if "fastrtps" in f or f.startswith("sem.")}


def _stop(pids: set[int]) -> None:
    """SIGTERM, a bounded wait, then SIGKILL: what ``ray stop`` does, but only to the
    processes this test started (found by its own Ray temp folder)."""
    import signal

    for sig in (signal.SIGTERM, signal.SIGKILL):
        for pid in pids:
            try:
                os.kill(pid, sig)
            except ProcessLookupError:
                pass
        for _ in range(50):
            pids = {p for p in pids if alive(p)}
            if not pids:
                return
            time.sleep(0.1)


def test_a_two_node_cluster_runs_the_cells_as_the_embedded_ray_does(no_leaks, ray_tmp,
                                                                    tmp_path):
    import socket

    shm_before = set(os.listdir("/dev/shm"))
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    # A cluster of several nodes cannot use Ray's loopback-only mode (Ray refuses); token
    # authentication on, as Ray's own default for ray.init.
    import secrets

    env = {**os.environ, "RAY_TMPDIR": str(ray_tmp), "RAY_AUTH_MODE": "token",
           "RAY_AUTH_TOKEN": secrets.token_hex(32)}  # this cluster's own, not ~/.ray's
    for name in ("RAY_ADDRESS", LOOPBACK_ENV):
        env.pop(name, None)
    ray_bin = str(Path(sys.executable).parent / "ray")
    address = f"127.0.0.1:{port}"
    spec_file = tmp_path / "two.yaml"
    spec_file.write_text(yaml.safe_dump({**TINY, "worlds": [str(WORLDS / "table1.yaml")]}))
    out = tmp_path / "sweep"
    try:
        for cmd in ([ray_bin, "start", "--head", "--node-ip-address", "127.0.0.1", "--port",
                     str(port), "--num-cpus", "1", "--include-dashboard", "false",
                     "--disable-usage-stats"],
                    [ray_bin, "start", "--address", address, "--node-ip-address",
                     "127.0.0.1", "--num-cpus", "1", "--resources", '{"second_node": 1}',
                     "--disable-usage-stats"]):
            proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=120)
            assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
        proc = subprocess.run([sys.executable, "-m", "roger_bringup.cli", "sweep",
                               str(spec_file), "--out", str(out), "--address", address,
                               "--quiet"], env=env, capture_output=True, text=True,
                              timeout=300)
        assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    finally:
        _stop(_ray_pids(str(ray_tmp)))
    assert not _ray_pids(str(ray_tmp))
    assert not (set(os.listdir("/dev/shm")) - shm_before - _roger_shm())
    folders = list((out / "cells").iterdir())
    assert len(folders) == 2
    # One run on each node (two 1-CPU nodes, two runs in flight), each equal to the same
    # cell run in this process.
    nodes = {json.loads((f / "worker.json").read_text())["node"] for f in folders}
    assert len(nodes) == 2, nodes
    for folder in folders:
        cell = json.loads((folder / "cell.json").read_text())
        run = RunSpec(cell["world"], Path(cell["world"]).read_text(), cell["policy"],
                      cell["seed"], cell["budget"], cell["features"])
        run_in_process(run, tmp_path / "here" / folder.name)
        assert ((tmp_path / "here" / folder.name / "cycles.csv").read_text()
                == (folder / "cycles.csv").read_text())


def test_a_killed_runs_scratch_folder_is_removed_by_the_next_run(tmp_path, monkeypatch) -> None:
    """A worker killed mid-run leaves its scratch folder; the next scratch folder made on
    that machine removes the folders of dead makers, and only those."""
    from roger_experiments.runners import OWNER_FILE, remove_orphan_scratch, scratch_dir

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    folders = {}
    for name, owner in (("roger-run-dead", str(dead.pid)), ("roger-qtable-dead", str(dead.pid)),
                        ("roger-run-live", str(os.getpid())), ("roger-run-no-owner", None),
                        ("other-dead", str(dead.pid))):
        folders[name] = tmp_path / name
        folders[name].mkdir()
        if owner is not None:
            (folders[name] / OWNER_FILE).write_text(owner)
    made = scratch_dir("roger-run-")
    assert made.parent == tmp_path and (made / OWNER_FILE).read_text() == str(os.getpid())
    assert not folders["roger-run-dead"].exists() and not folders["roger-qtable-dead"].exists()
    assert all(folders[n].exists() for n in ("roger-run-live", "roger-run-no-owner",
                                             "other-dead"))
    assert remove_orphan_scratch(tmp_path) == 0  # the live maker's folders stay
    assert made.exists()


def test_a_job_runs_in_an_empty_folder_whatever_an_earlier_run_left_there(tmp_path):
    """``SequentialRunner`` gives each run an empty folder, as RayRunner does: a graph run
    loads the memory.pt it finds there, so an earlier run's long-term memory must not be
    left for it (a second ``make demo`` stored nothing)."""
    out = tmp_path / "runs" / "qlearning_seed0"
    out.mkdir(parents=True)
    (out / "memory.pt").write_bytes(b"an earlier run's memory")
    (out / "state").mkdir()
    (out / "state" / "sim.json").write_text("{}")
    seen: list[list[str]] = []

    def run_fn(spec, folder):
        seen.append(sorted(p.name for p in folder.rglob("*")) if folder.exists() else [])
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "metrics.json").write_text("{}")
        return {"cycles": 1}

    spec = RunSpec("w.yaml", "objects: []\n", "qlearning", 0, 1, "extended")
    results = list(SequentialRunner(run_fn)([Job(spec, out), Job(spec, out)]))
    assert [m for _, m in results] == [{"cycles": 1}, {"cycles": 1}]
    assert seen == [[], []]
    assert sorted(p.name for p in out.iterdir()) == ["metrics.json"]
