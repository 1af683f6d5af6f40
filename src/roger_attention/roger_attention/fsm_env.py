"""An abstract, FSM-only environment with stochastic match outcomes (section 4.2).

A unit-test fixture for the Q-learning code, with invented identification probabilities
(FsmEnvConfig): never a stand-in for the robot's results (``roger train`` learns on the
real core loop). Each step is one control cycle of Figure 3. The API follows Gymnasium:
``reset(seed) -> (obs, info)`` and ``step(action) -> (obs, reward, terminated, truncated,
info)``; the observation is the FSM ``State``.

The task is continuing, as the robot's (docs/attention.md): ``reset`` lands attention on a
random ROI and runs the match, an attention shift lands it on the next random ROI, a map
update settles the ROI in focus. Nothing terminates; an episode is truncated after
``max_episode_steps`` cycles.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from roger_attention.config import FsmEnvConfig
from roger_attention.fsm import (
    INITIAL_STATE,
    State,
    allowed_actions,
    check_allowed,
    reward,
    transition,
)
from roger_attention.qlearning import QTable
from roger_common.types import Action, MatchOutcome


class FsmEnv:
    """Figure 3's state machine driven by random ROIs and a random associative memory.

    Attributes:
        config: Probabilities, trial counts, rewards.
        state: Current FSM state.
    """

    def __init__(self, config: FsmEnvConfig | None = None, seed: int = 0) -> None:
        """Create the environment; ``reset`` must be called before ``step``."""
        self.config = config if config is not None else FsmEnvConfig()
        self._rng = np.random.default_rng(seed)
        self.state = INITIAL_STATE
        self._mapped = False
        self._known = False
        self._visual_left = 0
        self._haptic_left = 0
        self._steps = 0
        self._done = True

    def allowed(self) -> tuple[Action, ...]:
        """Actions the FSM allows now."""
        return allowed_actions(self.state, self._visual_left, self._haptic_left)

    def reset(self, seed: int | None = None) -> tuple[State, dict[str, Any]]:
        """Start an episode: attention lands on a random ROI and the match runs.

        Args:
            seed: Reseeds the environment's generator when given.
        """
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        self._steps = 0
        self._done = False
        outcome = self._shift()
        return self.state, self._info(outcome)

    def step(self, action: Action) -> tuple[State, float, bool, bool, dict[str, Any]]:
        """One control cycle.

        Raises:
            RuntimeError: The episode is over (call reset).
            IllegalActionError: The action is not allowed in the current state.
        """
        if self._done:
            raise RuntimeError("FsmEnv.step called on a finished episode; call reset()")
        action = Action(action)
        check_allowed(action, self.allowed(), self.state)
        before = self.state
        outcome: MatchOutcome | None = None
        if action is Action.ATTENTION_SHIFT:
            outcome = self._shift()
        elif action is Action.MAP_UPDATE:
            self.state = transition(before, action, None, True)
            self._mapped = True
        else:
            if action is Action.VISUAL_IMPROVEMENT:
                self._visual_left -= 1
            else:
                self._haptic_left -= 1
            outcome = self._match(action)
            self.state = transition(before, action, outcome, self._mapped)
        r = reward(before, action, self.state, self.config.rewards)
        self._steps += 1
        truncated = self._steps >= self.config.max_episode_steps
        self._done = truncated
        info = self._info(outcome)
        # A shift away from a ROI still to be mapped leaves it unsettled.
        info["abandoned"] = action is Action.ATTENTION_SHIFT and not before.mapping
        return self.state, r, False, truncated, info

    def _shift(self) -> MatchOutcome:
        """Attention lands on a fresh random ROI; the match after the shift runs."""
        cfg = self.config
        self._mapped = bool(self._rng.random() < cfg.p_mapped)
        # A mapped object was identified or stored, so memory holds it.
        self._known = self._mapped or bool(self._rng.random() < cfg.p_known)
        self._visual_left = cfg.visual_trials
        self._haptic_left = cfg.haptic_trials
        outcome = self._match(Action.ATTENTION_SHIFT)
        self.state = transition(self.state, Action.ATTENTION_SHIFT, outcome, self._mapped)
        return outcome

    def _match(self, action: Action) -> MatchOutcome:
        cfg = self.config
        if self._visual_left <= 0 and self._haptic_left <= 0:
            return MatchOutcome.IDENTIFIED if self._known else MatchOutcome.NEW
        p = {Action.ATTENTION_SHIFT: cfg.p_identify_shift,
             Action.VISUAL_IMPROVEMENT: cfg.p_identify_visual,
             Action.HAPTIC_IMPROVEMENT: cfg.p_identify_haptic}[action]
        if self._known and self._rng.random() < p:
            return MatchOutcome.IDENTIFIED
        return MatchOutcome.UNDETERMINED

    def _info(self, outcome: MatchOutcome | None) -> dict[str, Any]:
        return {"bits": self.state.bits, "allowed": self.allowed(), "mapped": self._mapped,
                "known": self._known, "outcome": None if outcome is None else outcome.name}


@dataclass
class TrainingLog:
    """What ``train_qtable`` saw, per episode.

    Attributes:
        td_errors: Every TD error, in order.
        episode_mean_abs_td: Mean |TD error| of each episode.
        returns: Sum of rewards of each episode.
        lengths: Cycles of each episode.
    """

    td_errors: list[float] = field(default_factory=list)
    episode_mean_abs_td: list[float] = field(default_factory=list)
    returns: list[float] = field(default_factory=list)
    lengths: list[int] = field(default_factory=list)


def train_qtable(env: FsmEnv, table: QTable, episodes: int, rng: np.random.Generator,
                 epsilon: float | None = None, seed: int | None = None) -> TrainingLog:
    """Epsilon-greedy Q-learning on the environment.

    Args:
        env: The environment.
        table: Updated in place.
        episodes: Number of episodes.
        rng: Exploration and tie-break randomness.
        epsilon: Exploration (default: the table's).
        seed: Seeds the environment at the first reset.

    Returns:
        The TD errors, returns and lengths.
    """
    log = TrainingLog()
    for episode in range(episodes):
        state, info = env.reset(seed=seed if episode == 0 else None)
        done, ret, tds = False, 0.0, []
        while not done:
            action = table.select_action(state, rng, info["allowed"], epsilon)
            next_state, r, terminated, truncated, info = env.step(action)
            tds.append(table.update(state, action, r, next_state, terminated,
                                    info["allowed"]))
            ret += r
            state = next_state
            done = terminated or truncated
        log.td_errors.extend(tds)
        log.episode_mean_abs_td.append(float(np.mean(np.abs(tds))))
        log.returns.append(ret)
        log.lengths.append(len(tds))
    return log
