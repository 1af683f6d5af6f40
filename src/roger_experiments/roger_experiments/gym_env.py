"""A Gymnasium environment over Roger's real core: simulator, perception, memory, attention.

``RogerAttentionEnv`` runs the same in-process loop as ``core_loop.CoreLoop`` (no ROS),
with the attention policy replaced by the agent: each ``step(action)`` is one control cycle
whose action is the agent's (sections 4.2 and 5 of the paper).

- Observation: the FSM state of Figure 3 as ``Discrete(6)``, the row of ``fsm.STATES``
  (000, 001, 010, 011, 100, 101). With ``features=True`` a ``Dict`` adds the focused ROI's
  feature vector (``feature_names(mode)``: equations 1-5, and the shape evidence in the
  extended mode) and its ``known`` mask (zeros without a
  focus).
- Actions: ``Discrete(4)``, the four actions of ``roger_common.types.Action``.
- Reward: the FSM's, from the attention configuration's RewardConfig: only the map updates
  100->101 and 010->011 earn one (section 4.2).
- Actions the FSM does not allow in the current state (``info["action_mask"]`` says which
  are allowed, every step): the step is a no-op, reward 0, nothing moves, no control cycle
  is counted, ``info["illegal"]`` is True. It still counts towards truncation.
- An attention shift with nothing in the spatial map (an empty view) is an idle look: no
  cycle is counted, reward 0, ``info["idle"]`` is True.
- Episodes: ``reset(seed=...)`` rebuilds the world, the robot and (unless ``keep_memory``)
  an empty long-term memory; an episode is truncated after ``max_cycles`` steps and never
  terminated (inspection has no final state: interest keeps attention moving, section 5),
  which is also how the attention node's Q-learning treats every transition (no update is
  terminal; docs/attention.md). ``info["roi_done"]`` marks the steps that leave the ROI in
  focus (a shift) or settle it (a map update), for agents that want to know;
  :func:`run_qlearning` trains a QTable as the attention node does.

Registered as ``Roger/Attention-v0``: ``gymnasium.make("Roger/Attention-v0", max_cycles=60)``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces

from roger_attention.config import AttentionConfig
from roger_attention.fsm import ACTIONS, STATES, State
from roger_attention.policies import FixedPolicy
from roger_attention.qlearning import QTable
from roger_common.errors import ConfigError, RogerError
from roger_common.types import Action, WorldSpec, feature_dim
from roger_experiments.core_loop import CoreLoop
from roger_experiments.evaluation import ACTION_NAMES
from roger_experiments.view import compose_view
from roger_memory.config import MemoryConfig
from roger_perception.config import PerceptionConfig
from roger_sim.config import SimConfig
from roger_sim.world import load_world

ENV_ID = "Roger/Attention-v0"
#: The world of ``roger run``'s default.
DEFAULT_WORLD = Path(__file__).resolve().parents[3] / "worlds" / "table1.yaml"


class _ActionRefused(RogerError):
    """The agent's action is not allowed in the state the cycle starts in."""


@dataclass
class ExternalPolicy(FixedPolicy):
    """A Policy (roger_attention.policies) that plays the action the agent gave to step();
    it learns nothing itself (the agent learns outside).

    Attributes:
        next_action: The action of the next control cycle.
    """

    name: str = "external"
    next_action: Action | None = field(default=None)

    def select_action(self, state: State, allowed: Sequence[Action]) -> Action:
        """The agent's action; refused (the step becomes a no-op) when not allowed."""
        if self.next_action is None or self.next_action not in allowed:
            raise _ActionRefused(f"{self.next_action} not allowed in {state.bits}")
        return self.next_action


class RogerAttentionEnv(gymnasium.Env):
    """One control cycle of the real robot per step, the agent choosing the action."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 4}

    def __init__(self, world: str | Path | WorldSpec = DEFAULT_WORLD, max_cycles: int = 204,
                 features: bool = False, render_mode: str | None = None,
                 keep_memory: bool = False, sim_config: SimConfig | None = None,
                 perception_config: PerceptionConfig | None = None,
                 memory_config: MemoryConfig | None = None,
                 attention_config: AttentionConfig | None = None) -> None:
        """Configure the environment; the world is built by ``reset``.

        Args:
            world: A world file or a loaded WorldSpec.
            max_cycles: Steps per episode before truncation (Table 2 used 204 cycles).
            features: Observe the focused ROI's features and known mask too.
            render_mode: None or "rgb_array" (``render()`` returns view.compose_view).
            keep_memory: Keep the long-term memory across resets (else each episode starts
                with an empty memory).
            sim_config, perception_config, memory_config, attention_config: The cores'
                configurations (defaults: those of ``roger run``).

        Raises:
            ConfigError: ``max_cycles`` < 1 or an unknown render mode.
            WorldFileError: The world file is unusable.
        """
        if not isinstance(max_cycles, int) or max_cycles < 1:
            raise ConfigError(f"RogerAttentionEnv.max_cycles must be an integer >= 1, "
                              f"got {max_cycles!r}")
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ConfigError(f"RogerAttentionEnv.render_mode must be None or 'rgb_array', "
                              f"got {render_mode!r}")
        self.world = world if isinstance(world, WorldSpec) else load_world(Path(world))
        self.max_cycles = max_cycles
        self.features = features
        self.render_mode = render_mode
        self.keep_memory = keep_memory
        self.configs: dict[str, Any] = {"sim_config": sim_config or SimConfig(),
                        "perception_config": perception_config or PerceptionConfig(),
                        "memory_config": memory_config or MemoryConfig()}
        # The agent's actions replace the policy's (``CoreLoop.agent``).
        self.attention_config = dataclasses.replace(attention_config or AttentionConfig(),
                                                    policy="straightforward")
        self.action_space = spaces.Discrete(len(ACTIONS))
        #: Length of the feature vector (the perception config's feature mode).
        self._dim = feature_dim(self.configs["perception_config"].features)
        state_space = spaces.Discrete(len(STATES))
        if features:
            self.observation_space = spaces.Dict({
                "state": state_space,
                "features": spaces.Box(0.0, 1.0, (self._dim,), np.float32),
                "known": spaces.MultiBinary(self._dim)})
        else:
            self.observation_space = state_space
        self.loop: CoreLoop | None = None
        self._policy = ExternalPolicy()
        self._steps = 0
        self._last: dict[str, Any] = {}

    # -- Gymnasium API -------------------------------------------------------------------
    def reset(self, *, seed: int | None = None,
              options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        """Rebuild the world and the robot; seed ``seed`` makes the episode reproducible."""
        super().reset(seed=seed)
        run_seed = int(self.np_random.integers(0, 2**31 - 1))
        memory = self.loop.memory if self.loop is not None and self.keep_memory else None
        self._close_loop()
        self.loop = CoreLoop(self.world, policy="straightforward", seed=run_seed,
                             attention_config=self.attention_config, learn=False,
                             memory=memory, agent=self._policy, **self.configs)
        self._steps = 0
        self._last = {"state_before": self._state().bits, "action": None, "bbox": None}
        return self._observation(), self._info(outcome="reset", illegal=False, idle=False,
                                               roi_done=False)

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        """One control cycle with the agent's action.

        Raises:
            RuntimeError: ``reset`` was not called.
            ValueError: ``action`` is not in the action space.
        """
        if self.loop is None:
            raise RuntimeError("RogerAttentionEnv.step called before reset()")
        if not self.action_space.contains(action):
            raise ValueError(f"action must be in {self.action_space}, got {action!r}")
        act = Action(int(action))
        before = self._state()
        self._policy.next_action = act
        illegal = idle = False
        reward, outcome, roi_done = 0.0, "illegal", False
        try:
            record = self.loop.step()
        except _ActionRefused:
            record, illegal = None, True
        if record is not None:
            reward, outcome = float(record.reward), record.outcome
            roi_done = record.action in (Action.ATTENTION_SHIFT, Action.MAP_UPDATE)
            self._last = {"state_before": before.bits, "action": act, "bbox": record.bbox}
        elif not illegal:
            idle, outcome = True, "idle"
        self._steps += 1
        truncated = self._steps >= self.max_cycles
        info = self._info(outcome=outcome, illegal=illegal, idle=idle, roi_done=roi_done)
        return self._observation(), reward, False, truncated, info

    def render(self) -> np.ndarray | None:
        """The view of the last cycle (``rgb_array`` mode), else None."""
        if self.render_mode != "rgb_array" or self.loop is None or \
                self.loop.last_frame is None:
            return None
        frame, sm = self.loop.last_frame, self.loop.ctl.spatial_map
        seen = [e for e in sm if e.last_frame == sm.frame]
        action = self._last.get("action")
        return compose_view(
            frame.left, frame.right, [e.roi for e in seen], self._last.get("bbox"),
            f"{self._last.get('state_before', '')}->{self._state().bits}",
            ACTION_NAMES.get(int(action), "") if action is not None else "",
            self.loop.ctl.counters.as_dict(), {e.roi.roi_id: e.interest for e in seen},
            scale=2)

    def close(self) -> None:
        """Release the simulator (idempotent)."""
        self._close_loop()

    # -- helpers -------------------------------------------------------------------------
    def action_mask(self) -> np.ndarray:
        """1 for each action the FSM allows now, in ``Action`` order (int8)."""
        mask = np.zeros(len(ACTIONS), np.int8)
        if self.loop is not None:
            for a in self.loop.ctl.allowed():
                mask[int(a)] = 1
        return mask

    def _state(self) -> State:
        assert self.loop is not None
        return self.loop.ctl.state  # the state the next cycle starts in

    def _observation(self) -> Any:
        state = self._state().index
        if not self.features:
            return state
        assert self.loop is not None
        entry = self.loop.ctl.spatial_map.get(self.loop.ctl.focus)
        feats = np.zeros(self._dim, np.float32)
        known = np.zeros(self._dim, np.int8)
        if entry is not None:
            feats = np.clip(np.asarray(entry.features, np.float32), 0.0, 1.0)
            known = np.asarray(entry.known, np.int8)
        return {"state": state, "features": feats, "known": known}

    def _info(self, outcome: str, illegal: bool, idle: bool, roi_done: bool) -> dict[str, Any]:
        assert self.loop is not None
        return {"action_mask": self.action_mask(), "bits": self._state().bits,
                "outcome": outcome, "illegal": illegal, "idle": idle, "roi_done": roi_done,
                "cycle": self.loop.ctl.counters.cycles,
                "counters": self.loop.ctl.counters.as_dict()}

    def _close_loop(self) -> None:
        if self.loop is not None:
            self.loop.close()
            self.loop = None


def allowed_from_mask(mask: np.ndarray) -> tuple[Action, ...]:
    """The allowed actions of an ``info["action_mask"]``."""
    return tuple(a for a in ACTIONS if mask[int(a)])


def run_qlearning(env: RogerAttentionEnv, table: QTable, episodes: int,
                  rng: np.random.Generator, seed: int | None = None,
                  epsilon: float | None = None) -> list[float]:
    """Train the repo's QTable against the environment, as the attention node does.

    Epsilon-greedy over the allowed actions; each cycle updates Q(s, a) with section 2's
    rule, never terminal (the environment never terminates; truncation bootstraps).

    Args:
        env: The environment (its observation must be the plain state, features=False).
        table: Updated in place.
        episodes: Episodes of ``env.max_cycles`` steps.
        rng: Exploration and tie-break randomness.
        seed: Seed of the first reset (later resets continue its generator).
        epsilon: Exploration probability (default: the table's).

    Returns:
        The TD error of every update, in order (Figure 6's curve).
    """
    if env.features:
        raise ConfigError("run_qlearning needs RogerAttentionEnv(features=False)")
    tds: list[float] = []
    for episode in range(episodes):
        obs, info = env.reset(seed=seed if episode == 0 else None)
        done = False
        while not done:
            state = STATES[obs]
            action = table.select_action(state, rng, allowed_from_mask(info["action_mask"]),
                                         epsilon)
            obs, reward, terminated, truncated, info = env.step(int(action))
            if not (info["illegal"] or info["idle"]):
                tds.append(table.update(state, action, reward, STATES[obs], terminated,
                                        allowed_from_mask(info["action_mask"])))
            done = terminated or truncated
    return tds


if ENV_ID not in gymnasium.registry:
    gymnasium.register(id=ENV_ID, entry_point="roger_experiments.gym_env:RogerAttentionEnv")
