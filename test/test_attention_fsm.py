"""The FSM of Figure 3: states, allowed actions, transitions, rewards; the straightforward
policy's table (section 4.1) and the FSM-only environment.

(That the core imports without ROS is checked elsewhere.)
"""

from __future__ import annotations

import numpy as np
import pytest

from roger_attention.config import FsmEnvConfig, RewardConfig
from roger_attention.fsm import (
    ACTIONS,
    INITIAL_STATE,
    STATES,
    IllegalActionError,
    State,
    allowed_actions,
    reward,
    transition,
)
from roger_attention.fsm_env import FsmEnv
from roger_attention.policies import StraightforwardPolicy
from roger_common.types import Action, MatchOutcome

S, V, H, M = (Action.ATTENTION_SHIFT, Action.VISUAL_IMPROVEMENT, Action.HAPTIC_IMPROVEMENT,
              Action.MAP_UPDATE)
ID, NEW, UND = MatchOutcome.IDENTIFIED, MatchOutcome.NEW, MatchOutcome.UNDETERMINED


def test_six_reachable_states_and_bits() -> None:
    assert [s.bits for s in STATES] == ["000", "001", "010", "011", "100", "101"]
    assert len(set(STATES)) == 6
    assert INITIAL_STATE.bits == "000"
    for s in STATES:
        assert State.from_bits(s.bits) == s
        assert STATES[s.index] == s
    assert len(ACTIONS) == 4


@pytest.mark.parametrize("bits", ["110", "111", "01", "0a1", "2000"])
def test_unreachable_or_malformed_states_rejected(bits: str) -> None:
    with pytest.raises(ValueError):
        State.from_bits(bits)


@pytest.mark.parametrize(
    ("bits", "visual_left", "haptic_left", "has_focus", "expected"),
    [
        ("000", 1, 1, True, {S, V, H}),
        ("001", 1, 1, True, {S, V, H}),
        ("000", 0, 1, True, {S, H}),
        ("000", 1, 0, True, {S, V}),
        ("000", 0, 0, True, {S}),
        ("010", 1, 1, True, {S, M}),
        ("100", 0, 0, True, {S, M}),
        ("011", 1, 1, True, {S}),
        ("101", 0, 0, True, {S}),
        ("010", 1, 1, False, {S}),
        ("000", 1, 1, False, {S}),
    ],
)
def test_allowed_actions_table(bits: str, visual_left: int, haptic_left: int,
                               has_focus: bool, expected: set[Action]) -> None:
    got = allowed_actions(State.from_bits(bits), visual_left, haptic_left, has_focus)
    assert set(got) == expected
    assert list(got) == sorted(got)


@pytest.mark.parametrize(
    ("bits", "action", "outcome", "mapped", "expected"),
    [
        # A shift: novelty and identity come from the match after it, mapping from the
        # new focus.
        ("011", S, UND, False, "000"),
        ("011", S, UND, True, "001"),
        ("101", S, ID, False, "010"),
        ("000", S, ID, True, "011"),
        ("000", S, None, False, "000"),   # focus lost from view: undetermined
        ("010", S, NEW, False, "100"),
        # Improvements re-run the match.
        ("000", V, UND, False, "000"),
        ("000", V, ID, False, "010"),
        ("000", H, ID, False, "010"),
        ("000", H, NEW, False, "100"),
        ("001", V, ID, True, "011"),
        ("001", H, NEW, True, "101"),
        # Map updates set the mapping bit and keep the rest.
        ("010", M, None, True, "011"),
        ("100", M, None, True, "101"),
        ("010", M, ID, False, "011"),     # outcome and mapped are ignored
    ],
)
def test_transition_table(bits: str, action: Action, outcome: MatchOutcome | None,
                          mapped: bool, expected: str) -> None:
    assert transition(State.from_bits(bits), action, outcome, mapped).bits == expected


@pytest.mark.parametrize("bits", ["000", "001", "011", "101"])
def test_map_update_illegal_unless_decided_and_unmapped(bits: str) -> None:
    with pytest.raises(IllegalActionError, match=bits):
        transition(State.from_bits(bits), M, None, True)


REWARDS = RewardConfig(unmapped=1.0, new_object=10.0, identification=100.0)


@pytest.mark.parametrize(
    ("bits", "action", "next_bits", "expected"),
    [
        ("100", M, "101", 11.0),    # circumstances (a) + (b)
        ("010", M, "011", 101.0),   # circumstances (a) + (c)
        ("000", S, "010", 0.0),
        ("000", V, "010", 0.0),
        ("000", H, "100", 0.0),
        ("001", V, "011", 0.0),
        ("011", S, "000", 0.0),
        ("101", S, "001", 0.0),
        ("010", S, "000", 0.0),
        ("100", S, "000", 0.0),
    ],
)
def test_reward_table(bits: str, action: Action, next_bits: str, expected: float) -> None:
    got = reward(State.from_bits(bits), action, State.from_bits(next_bits), REWARDS)
    assert got == pytest.approx(expected)


def test_every_legal_transition_rewarded_only_on_the_two_map_updates() -> None:
    rewarded = set()
    for s in STATES:
        for a in allowed_actions(s):
            for outcome in (ID, NEW, UND, None):
                for mapped in (False, True):
                    s2 = transition(s, a, outcome, mapped)
                    assert s2 in STATES
                    if reward(s, a, s2, REWARDS) > 0:
                        rewarded.add((s.bits, a, s2.bits))
    assert rewarded == {("100", M, "101"), ("010", M, "011")}


@pytest.mark.parametrize(
    ("bits", "visual_left", "haptic_left", "expected"),
    [
        ("000", 1, 1, V),   # Step 2: not identified after the shift -> visual improvement
        ("000", 0, 1, H),   # Step 3: not identified after it -> haptic improvement
        ("010", 0, 1, M),   # Steps 2-4: identified -> update the map
        ("100", 0, 0, M),   # Step 4: new -> store and update the map
        ("011", 0, 0, S),   # Step 1: re-direct the attention
        ("101", 0, 0, S),
        ("001", 1, 1, V),   # a mapped entry not recognised: same steps
        ("000", 0, 0, S),   # lost with no trial left
    ],
)
def test_straightforward_policy_table(bits: str, visual_left: int, haptic_left: int,
                                      expected: Action) -> None:
    state = State.from_bits(bits)
    allowed = allowed_actions(state, visual_left, haptic_left)
    assert StraightforwardPolicy().select_action(state, allowed) is expected


def test_env_api_and_final_trial_always_decides() -> None:
    env = FsmEnv(FsmEnvConfig(p_mapped=0.0, p_identify_shift=0.0, p_identify_visual=0.0,
                              p_identify_haptic=0.0))
    obs, info = env.reset(seed=3)
    assert obs.bits == "000" and set(info["allowed"]) == {S, V, H}
    obs, r, terminated, truncated, info = env.step(V)
    assert (obs.bits, r, terminated, truncated) == ("000", 0.0, False, False)
    obs, r, terminated, truncated, info = env.step(H)   # the final trial
    assert obs.bits in ("010", "100")
    assert obs.bits == ("010" if info["known"] else "100")
    obs, r, terminated, truncated, info = env.step(M)
    assert not terminated and not truncated and r > 0 and obs.mapping == 1
    assert info["allowed"] == (S,)
    obs, r, terminated, truncated, info = env.step(S)   # the task goes on: the next ROI
    assert not terminated and obs.bits == "000" and set(info["allowed"]) == {S, V, H}


def test_env_rejects_illegal_actions_and_a_shift_lands_on_the_next_roi() -> None:
    env = FsmEnv(FsmEnvConfig(p_mapped=0.0, p_identify_shift=0.0))
    env.reset(seed=0)
    with pytest.raises(IllegalActionError):
        env.step(M)
    obs, r, terminated, _, info = env.step(S)
    assert not terminated and r == 0.0 and info["abandoned"]
    assert obs.bits == "000" and set(info["allowed"]) == {S, V, H}   # trials refilled


def test_env_never_terminates_and_truncates() -> None:
    env = FsmEnv(FsmEnvConfig(max_episode_steps=1, visual_trials=5, p_identify_shift=0.0,
                              p_identify_visual=0.0))
    env.reset(seed=0)
    _, _, terminated, truncated, _ = env.step(V)
    assert truncated and not terminated
    with pytest.raises(RuntimeError):
        env.step(S)


def test_env_same_seed_same_trajectory() -> None:
    def trajectory(seed: int) -> list[str]:
        env, rng, out = FsmEnv(), np.random.default_rng(seed), []
        for episode in range(30):
            obs, info = env.reset(seed=seed if episode == 0 else None)
            done = False
            while not done:
                a = info["allowed"][int(rng.integers(len(info["allowed"])))]
                obs, _, term, trunc, info = env.step(a)
                out.append(f"{a.name}:{obs.bits}")
                done = term or trunc
        return out

    assert trajectory(5) == trajectory(5)
    assert trajectory(5) != trajectory(6)
