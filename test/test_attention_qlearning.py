"""Tabular Q-learning (section 4.2): the update rule, epsilon-greedy choice, atomic files,
convergence on the FSM-only environment, and the policy switch.

(That the core imports without ROS is checked elsewhere.)
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from roger_attention.config import AttentionConfig, FsmEnvConfig, QLearningConfig
from roger_attention.fsm import State, allowed_actions
from roger_attention.fsm_env import FsmEnv, train_qtable
from roger_attention.policies import (
    Policy,
    QLearningPolicy,
    StraightforwardPolicy,
    make_policy,
)
from roger_attention.qlearning import QTable
from roger_common.errors import ConfigError, MemoryFileError
from roger_common.types import Action

S, V, H, M = (Action.ATTENTION_SHIFT, Action.VISUAL_IMPROVEMENT, Action.HAPTIC_IMPROVEMENT,
              Action.MAP_UPDATE)
S000, S010, S011, S100 = (State.from_bits(b) for b in ("000", "010", "011", "100"))


def test_paper_defaults() -> None:
    cfg = QLearningConfig()
    assert (cfg.alpha, cfg.gamma) == (0.5, 0.1)


def test_update_rule_terminal_and_not() -> None:
    t = QTable(QLearningConfig(alpha=0.5, gamma=0.1))
    td = t.update(S010, M, 2.0, S011, terminated=True)
    assert td == pytest.approx(2.0)
    assert t.value(S010, M) == pytest.approx(1.0)           # 0 + 0.5 * (2 - 0)
    t.q[S010.index, int(M)] = 4.0
    t.q[S010.index, int(S)] = 9.0   # not in next_allowed below: must be ignored
    td = t.update(S000, V, 0.0, S010, terminated=False, next_allowed=(M,))
    assert td == pytest.approx(0.1 * 4.0)
    assert t.value(S000, V) == pytest.approx(0.5 * 0.4)
    td = t.update(S000, V, 0.0, S010, terminated=False)      # default A(s') includes S
    assert td == pytest.approx(0.1 * 9.0 - 0.2)
    assert t.td_errors == pytest.approx([2.0, 0.4, 0.9 - 0.2])


def test_select_action_greedy_random_ties_and_exploration() -> None:
    t = QTable()
    rng = np.random.default_rng(0)
    allowed = allowed_actions(S000)
    tied = {t.select_action(S000, rng, allowed, epsilon=0.0) for _ in range(200)}
    assert tied == {S, V, H}                       # all tied at 0: random tie-breaks
    t.q[S000.index, int(H)] = 1.0
    greedy = {t.select_action(S000, rng, allowed, epsilon=0.0) for _ in range(200)}
    assert greedy == {H}
    t.q[S000.index, int(M)] = 5.0                   # not allowed in 000: never chosen
    explore = [t.select_action(S000, rng, allowed, epsilon=1.0) for _ in range(300)]
    assert set(explore) == {S, V, H}


def test_save_load_roundtrip_atomic(tmp_path: Path) -> None:
    t = QTable(QLearningConfig(alpha=0.3, gamma=0.2, epsilon=0.05))
    t.q[:] = np.arange(t.q.size, dtype=float).reshape(t.q.shape) / 7.0
    path = tmp_path / "sub" / "q.json"
    t.save(path)
    assert sorted(p.name for p in path.parent.iterdir()) == ["q.json"]   # no temp left
    back = QTable.load(path)
    np.testing.assert_array_equal(back.q, t.q)
    assert (back.config.alpha, back.config.gamma, back.config.epsilon) == (0.3, 0.2, 0.05)
    t.q[0, 0] = -1.0
    t.save(path)                                    # overwrite
    assert QTable.load(path).q[0, 0] == -1.0


@pytest.mark.parametrize(
    "content",
    [b"{not json", b"[1, 2]", b'{"format": "other"}', b"\xff\xfe",
     None],  # None: a valid file with a wrong-shaped table, built below
)
def test_corrupt_file_names_it(tmp_path: Path, content: bytes | None) -> None:
    path = tmp_path / "bad.json"
    if content is None:
        data = QTable().to_dict()
        data["q"] = [[0.0] * 4] * 5
        content = json.dumps(data).encode()
    path.write_bytes(content)
    with pytest.raises(MemoryFileError, match="bad.json"):
        QTable.load(path)


def test_missing_file_names_it(tmp_path: Path) -> None:
    with pytest.raises(MemoryFileError, match="nothere.json"):
        QTable.load(tmp_path / "nothere.json")


def _train(seed: int, episodes: int = 300,
           env_cfg: FsmEnvConfig | None = None) -> tuple[QTable, list[float]]:
    env = FsmEnv(env_cfg)
    table = QTable()
    log = train_qtable(env, table, episodes, np.random.default_rng(seed), seed=seed)
    return table, log.td_errors


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_td_error_falls_to_the_noise_of_the_next_rois_match(seed: int) -> None:
    table, td = _train(seed)
    first, last = float(np.mean(np.abs(td[:100]))), float(np.mean(np.abs(td[-2000:])))
    assert last < 0.8 * first, (first, last)
    # The rewarded map updates converge to r + gamma Q(s', shift) (nothing is terminal).
    for bits, r in (("010", 2.0), ("100", 1.5)):
        s, s2 = State.from_bits(bits), State.from_bits(bits[:2] + "1")
        target = r + 0.1 * table.value(s2, S)
        assert table.value(s, M) == pytest.approx(target, abs=0.02), (bits, table.q)


def test_training_is_reproducible() -> None:
    a, _ = _train(4, 100)
    b, _ = _train(4, 100)
    c, _ = _train(5, 100)
    np.testing.assert_array_equal(a.q, b.q)
    assert not np.array_equal(a.q, c.q)


@pytest.mark.parametrize("p_mapped", [0.0, 0.25])
def test_greedy_policy_settles_every_unmapped_roi_where_improving_pays(
        p_mapped: float) -> None:
    # In this fixture an improvement identifies a known object more often (0.5, 0.7) than
    # the next ROI's match after a shift does (0.3): the learnt values must say so.
    cfg = FsmEnvConfig(p_mapped=p_mapped)
    table, _ = _train(7, 300, cfg)
    s000 = State.from_bits("000")
    assert max(table.value(s000, V), table.value(s000, H)) > table.value(s000, S) > 0.0
    policy = QLearningPolicy(table, np.random.default_rng(1), learn=False)
    env = FsmEnv(FsmEnvConfig(p_mapped=p_mapped, max_episode_steps=2000))
    state, info = env.reset(seed=11)
    landed_unmapped, stays, actions = not info["mapped"], 0, []
    for _ in range(2000):
        a = policy.select_action(state, info["allowed"])
        if a is S:
            if landed_unmapped:
                stays += 1
                assert actions and actions[-1] is M, actions   # settled before leaving
            actions = []
        else:
            actions.append(a)
        state, _, terminated, _, info = env.step(a)
        assert not terminated
        if a is S:
            landed_unmapped = not info["mapped"]
    assert stays > 100


def test_make_policy_switch_and_modes(tmp_path: Path) -> None:
    cfg = AttentionConfig()
    rng = np.random.default_rng(0)
    sf = make_policy("straightforward", cfg, rng)
    assert isinstance(sf, StraightforwardPolicy) and not sf.learns
    assert isinstance(sf, Policy)
    ql = make_policy("qlearning", cfg, rng)                 # training from scratch
    assert isinstance(ql, QLearningPolicy) and ql.learns and isinstance(ql, Policy)
    assert ql.update(S010, M, 2.0, S011, True, (S,)) == pytest.approx(2.0)
    path = tmp_path / "q.json"
    ql.save(path)
    runner = make_policy("qlearning", cfg, rng, qtable_path=path, learn=False)
    assert isinstance(runner, QLearningPolicy) and not runner.learns
    assert runner.table.value(S010, M) == pytest.approx(1.0)
    assert runner.select_action(S010, (S, M)) is M
    before = runner.table.q.copy()
    assert runner.update(S010, M, 2.0, S011, True, (S,)) is None
    np.testing.assert_array_equal(runner.table.q, before)
    resumed = make_policy("qlearning", cfg, rng, qtable_path=path, learn=True)
    assert resumed.table.value(S010, M) == pytest.approx(1.0)
    with pytest.raises(ConfigError, match="qtable_path"):
        make_policy("qlearning", cfg, rng, learn=False)
    with pytest.raises(MemoryFileError, match="missing.json"):
        make_policy("qlearning", cfg, rng, qtable_path=tmp_path / "missing.json", learn=False)
    with pytest.raises(ConfigError, match="greedy"):
        make_policy("greedy", cfg, rng)


def test_the_visits_step_size_decays_with_each_pairs_own_updates(tmp_path: Path) -> None:
    t = QTable(QLearningConfig(alpha=0.5, gamma=0.0, alpha_schedule="visits", alpha_k=2.0))
    steps = []
    for _ in range(4):
        steps.append(t.step_size(S010, M))
        t.update(S010, M, 1.0, S011, terminated=True)
    assert steps == pytest.approx([0.5, 0.5 / 1.5, 0.5 / 2.0, 0.5 / 2.5])
    assert t.step_size(S000, V) == 0.5  # another pair keeps its own count
    q = 0.0
    for a in steps:
        q += a * (1.0 - q)
    assert t.value(S010, M) == pytest.approx(q)
    # The paper's constant: every update steps by alpha.
    c = QTable(QLearningConfig(alpha=0.5))
    c.update(S010, M, 1.0, S011, terminated=True)
    assert c.step_size(S010, M) == 0.5 and c.visits[S010.index, int(M)] == 1
    # The counts travel with the table: trained further, it goes on where it stopped.
    t.save(tmp_path / "q.json")
    back = QTable.load(tmp_path / "q.json")
    assert back.config.alpha_schedule == "visits" and back.config.alpha_k == 2.0
    assert back.step_size(S010, M) == pytest.approx(0.5 / 3.0)
    # A table written before the schedule existed loads as constant, no visits.
    raw = json.loads((tmp_path / "q.json").read_text())
    for key in ("alpha_schedule", "alpha_k", "visits"):
        del raw[key]
    (tmp_path / "old.json").write_text(json.dumps(raw))
    old = QTable.load(tmp_path / "old.json")
    assert old.config.alpha_schedule == "constant" and not old.visits.any()


def test_a_step_size_that_decays_settles_where_the_constant_one_keeps_jumping() -> None:
    """Noisy rewards (the robot's): the last 200 of 2000 updates of one pair move the
    paper's constant-alpha value by far more than the decaying one's."""
    rng = np.random.default_rng(5)
    rewards = rng.choice([0.0, 1.0], size=2000, p=[0.7, 0.3])
    spread = {}
    for schedule in ("constant", "visits"):
        t = QTable(QLearningConfig(alpha_schedule=schedule))
        tail = []
        for i, r in enumerate(rewards):
            t.update(S010, M, float(r), S011, terminated=True)
            if i >= 1800:
                tail.append(t.value(S010, M))
        spread[schedule] = max(tail) - min(tail)
    assert spread["visits"] < 0.25 * spread["constant"], spread


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [({"alpha": 0.0}, "alpha"), ({"alpha": 1.5}, "alpha"), ({"gamma": -0.1}, "gamma"),
     ({"epsilon": 2.0}, "epsilon"), ({"gamma": float("nan")}, "gamma"),
     ({"alpha_schedule": "cosine"}, "alpha_schedule"), ({"alpha_k": 0.0}, "alpha_k")],
)
def test_qlearning_config_rejects(kwargs: dict[str, float], field: str) -> None:
    with pytest.raises(ConfigError, match=field):
        QLearningConfig(**kwargs)


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [({"policy": "random"}, "policy"), ({"visual_trials": -1}, "visual_trials"),
     ({"haptic_trials": 1.5}, "haptic_trials")],
)
def test_attention_config_rejects(kwargs: dict[str, object], field: str) -> None:
    with pytest.raises(ConfigError, match=field):
        AttentionConfig(**kwargs)


def test_a_table_keeps_its_step_size_schedule_when_loaded_with_a_run_config(
        tmp_path: Path) -> None:
    """``roger train --alpha-schedule visits`` seeds the table with its schedule; every
    training run loads it with the run's own QLearningConfig (constant by default)."""
    from roger_experiments.train import fresh_table
    fresh_table(tmp_path, "visits")
    table = QTable.load(tmp_path / "qtable.json", QLearningConfig(epsilon=0.2))
    assert table.config.alpha_schedule == "visits" and table.config.epsilon == 0.2
    fresh_table(tmp_path, "constant")
    assert not (tmp_path / "qtable.json").exists()  # the paper's: a fresh default table


def test_figure_6_rebuilds_q_with_the_tables_own_step_sizes() -> None:
    """train.q_history replays the TD errors with the schedule the table learnt with."""
    from roger_experiments.train import TrainingLog
    for schedule, k in (("constant", None), ("visits", 3.0)):
        t = QTable(QLearningConfig(alpha_schedule=schedule, alpha_k=k or 20.0, gamma=0.0))
        tds = [t.update(S010, M, r, S011, terminated=True) for r in (1.0, 0.0, 2.0, 1.0, 1.0)]
        log = TrainingLog(np.array(tds), [0], ["010"] * 5, ["map_update"] * 5)
        history = log.q_history(0.5, (("010", "map_update"),), alpha_k=k)
        assert list(history.values())[0][-1] == pytest.approx(t.value(S010, M)), schedule
