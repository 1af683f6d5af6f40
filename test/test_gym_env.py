"""The Gymnasium environment over the real core (issue 10, item 3); no ROS needed."""

from __future__ import annotations

import warnings

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from roger_attention.config import QLearningConfig
from roger_attention.fsm import STATES, State
from roger_attention.qlearning import QTable
from roger_common.errors import ConfigError
from roger_common.types import Action, feature_dim
from roger_experiments.gym_env import ENV_ID, RogerAttentionEnv, allowed_from_mask, run_qlearning
from roger_memory.config import MemoryConfig

#: A memory that learns a new object in a few replay steps keeps each step fast.
FAST_MEMORY = MemoryConfig(train_steps=10, max_train_steps=50)


def make(**kw):
    return gymnasium.make(ENV_ID, memory_config=FAST_MEMORY, **kw)


@pytest.mark.parametrize("features", [False, True])
def test_env_passes_gymnasiums_checker(features):
    env = make(max_cycles=8, features=features, render_mode="rgb_array")
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            check_env(env.unwrapped, skip_render_check=False)
        complaints = [str(w.message) for w in caught if "WARN" in str(w.message)]
        assert not complaints, complaints
    finally:
        env.close()


def test_random_episodes_follow_the_fsm_and_table2_identities():
    env = make(max_cycles=25)
    rng = np.random.default_rng(5)
    seen_reward = illegal_seen = 0
    try:
        for episode in range(2):
            obs, info = env.reset(seed=11 + episode)
            assert obs == STATES.index(STATES[0]) and info["cycle"] == 0
            for _ in range(25):
                action = int(rng.integers(4))  # illegal ones included
                before_obs, before_cycle = obs, info["cycle"]
                allowed = allowed_from_mask(info["action_mask"])
                obs, reward, terminated, truncated, info = env.step(action)
                assert not terminated
                if Action(action) not in allowed:
                    illegal_seen += 1
                    assert info["illegal"] and reward == 0.0
                    assert obs == before_obs and info["cycle"] == before_cycle
                elif not info["idle"]:
                    assert info["cycle"] == before_cycle + 1
                if reward > 0:
                    seen_reward += 1
                    assert action == Action.MAP_UPDATE
                    assert (STATES[before_obs].bits, STATES[obs].bits) in \
                        (("100", "101"), ("010", "011"))
                c = info["counters"]
                assert c["attention_shifts"] + c["improvements"] + c["map_updates"] == c["cycles"]
                assert c["map_updates"] == (c["positive_identifications"] + c["new_objects"]
                                             + c["remaps"])
                if truncated:
                    break
            assert truncated
    finally:
        env.close()
    assert illegal_seen > 0 and seen_reward > 0


def test_same_seed_same_episode():
    def trajectory():
        env = make(max_cycles=12)
        try:
            obs, info = env.reset(seed=4)
            out = [obs]
            rng = np.random.default_rng(0)
            for _ in range(12):
                a = int(rng.choice(np.flatnonzero(info["action_mask"])))
                obs, r, _, _, info = env.step(a)
                out.append((obs, r, info["outcome"]))
            return out
        finally:
            env.close()
    assert trajectory() == trajectory()


def test_feature_observation_and_render():
    env = RogerAttentionEnv(max_cycles=5, features=True, render_mode="rgb_array",
                            memory_config=FAST_MEMORY)
    try:
        obs, _ = env.reset(seed=2)
        assert not obs["known"].any()  # no focus before the first shift
        obs, *_ = env.step(int(Action.ATTENTION_SHIFT))
        assert env.observation_space.contains(obs)
        assert obs["features"].shape == (feature_dim(FAST_MEMORY.features),) and obs["known"].any()
        view = env.render()
        size = env.configs["sim_config"].image_size
        assert view.dtype == np.uint8 and view.shape[0] > 2 * size
    finally:
        env.close()
    with pytest.raises(ConfigError):
        RogerAttentionEnv(max_cycles=0)


def test_qtable_trained_against_the_env_learns_the_rewarded_map_updates():
    env = RogerAttentionEnv(max_cycles=40, memory_config=FAST_MEMORY)
    table = QTable(QLearningConfig(epsilon=0.3))
    try:
        tds = run_qlearning(env, table, episodes=1, rng=np.random.default_rng(1), seed=3)
    finally:
        env.close()
    assert len(tds) >= 30 and len(tds) == len(table.td_errors)
    rewarded = [s for s in ("100", "010")
                if table.value(State.from_bits(s), Action.MAP_UPDATE) > 0]
    assert rewarded, f"no rewarded map update learned; Q =\n{table.q}"
    # Nothing is terminal: a shift after a rewarded map update is worth what the state it
    # lands in is worth, so the value reaches the shifts too.
    positive = {(STATES[i].bits, Action(j).name) for i, j in zip(*np.nonzero(table.q > 1e-9))}
    assert any(action == "ATTENTION_SHIFT" for _, action in positive), table.q
