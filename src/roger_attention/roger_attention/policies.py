"""The two attentional-control policies behind one protocol (sections 4.1 and 4.2)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from roger_attention.config import POLICY_NAMES, AttentionConfig
from roger_attention.fsm import State, check_allowed
from roger_attention.qlearning import QTable
from roger_common.errors import ConfigError
from roger_common.types import Action


@runtime_checkable
class Policy(Protocol):
    """What the AttentionController asks of a policy."""

    name: str

    @property
    def learns(self) -> bool:
        """True when ``update`` changes the policy (Q-learning in training mode)."""
        ...

    def select_action(self, state: State, allowed: Sequence[Action]) -> Action:
        """The action of the next control cycle, one of ``allowed``."""
        ...

    def update(self, state: State, action: Action, reward: float, next_state: State,
               terminated: bool, next_allowed: Sequence[Action]) -> float | None:
        """Learn from one transition; the TD error, or None when nothing is learnt."""
        ...

    def state_dict(self) -> dict[str, Any]:
        """What the policy has learnt, as JSON-ready data (to resume after a crash)."""
        ...

    def save(self, path: str | os.PathLike[str], durable: bool = True) -> None:
        """Write what the policy learnt to ``path`` atomically (nothing if it learns nothing)."""
        ...

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Take back what :meth:`state_dict` gave; ValueError when it does not fit."""
        ...


class FixedPolicy:
    """A policy that learns nothing: the four learning methods of Policy as no-ops.

    Subclasses give ``name`` and ``select_action`` (the straightforward policy; the Gym
    environment's policy, whose agent learns outside).
    """

    name = "fixed"

    @property
    def learns(self) -> bool:
        """Never."""
        return False

    def select_action(self, state: State, allowed: Sequence[Action]) -> Action:
        """The action of the next control cycle, one of ``allowed``."""
        raise NotImplementedError

    def update(self, state: State, action: Action, reward: float, next_state: State,
               terminated: bool, next_allowed: Sequence[Action]) -> float | None:
        """Nothing to learn."""
        return None

    def state_dict(self) -> dict[str, Any]:
        """Nothing learnt: an empty dict."""
        return {}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Nothing to restore."""

    def save(self, path: str | os.PathLike[str], durable: bool = True) -> None:
        """Nothing to save."""


class StraightforwardPolicy(FixedPolicy):
    """Steps 0-4 of section 4.1, read off the FSM state.

    After a shift (Step 1) the match has run. If the object is identified, update the map
    (Step 2); otherwise improve visually, then haptically (Steps 2-3); once the final trial
    concluded (identified, or new and stored by the map update) update the map (Step 4) and
    shift again. An entry already mapped whose identity is confirmed needs no map update:
    the policy shifts on.
    """

    name = "straightforward"

    def select_action(self, state: State, allowed: Sequence[Action]) -> Action:
        """Map update when allowed, else visual, then haptic improvement, else a shift."""
        if Action.MAP_UPDATE in allowed:
            return Action.MAP_UPDATE  # Steps 2-4: identified, or new (stored on update)
        if not state.decided:
            for action in (Action.VISUAL_IMPROVEMENT, Action.HAPTIC_IMPROVEMENT):
                if action in allowed:
                    return action  # Step 2 then Step 3
        check_allowed(Action.ATTENTION_SHIFT, allowed, state)
        return Action.ATTENTION_SHIFT


class QLearningPolicy:
    """Epsilon-greedy over a Q-table while learning, greedy when running (section 4.2).

    Attributes:
        table: The Q-table (shared, not copied).
        rng: Source of exploration and tie-break randomness.
        learn: Training mode (explore and update) or running mode (greedy, frozen).
    """

    name = "qlearning"

    def __init__(self, table: QTable, rng: np.random.Generator, learn: bool = True,
                 epsilon: float | None = None) -> None:
        """Wrap ``table``; ``epsilon`` defaults to the table's configured exploration."""
        self.table = table
        self.rng = rng
        self.learn = learn
        self.epsilon = table.config.epsilon if epsilon is None else epsilon

    @property
    def learns(self) -> bool:
        """True in training mode."""
        return self.learn

    def select_action(self, state: State, allowed: Sequence[Action]) -> Action:
        """Epsilon-greedy (training) or greedy (running), random tie-breaks."""
        eps = self.epsilon if self.learn else 0.0
        return self.table.select_action(state, self.rng, allowed, eps)

    def update(self, state: State, action: Action, reward: float, next_state: State,
               terminated: bool, next_allowed: Sequence[Action]) -> float | None:
        """One Q-learning update in training mode; None when running."""
        if not self.learn:
            return None
        return self.table.update(state, action, reward, next_state, terminated, next_allowed)

    def save(self, path: str | os.PathLike[str], durable: bool = True) -> None:
        """Save the Q-table atomically (``durable``: see atomic_write_bytes)."""
        self.table.save(path, durable=durable)

    def state_dict(self) -> dict[str, Any]:
        """The Q-values, as nested lists."""
        return {"q": self.table.q.tolist()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Set the Q-values; ValueError unless they are a finite table of this shape."""
        q = np.asarray(state["q"], dtype=float)
        if q.shape != self.table.q.shape or not np.all(np.isfinite(q)):
            raise ValueError(f"Q-table of shape {q.shape}, expected {self.table.q.shape}")
        self.table.q[...] = q


def make_policy(name: str, config: AttentionConfig, rng: np.random.Generator,
                qtable_path: str | os.PathLike[str] | None = None,
                learn: bool = True) -> StraightforwardPolicy | QLearningPolicy:
    """Build a policy by name; the switch of issue item 7.

    Args:
        name: "straightforward" or "qlearning".
        config: Supplies the Q-learning parameters.
        rng: Exploration randomness of the Q-learning policy.
        qtable_path: Q-table file. Training starts from it when it exists (else from a
            fresh table); running requires it.
        learn: Training (True) or running with a learned table (False).

    Raises:
        ConfigError: Unknown name, or running mode without a Q-table file.
        MemoryFileError: The Q-table file is missing (running mode) or corrupt.
    """
    if name not in POLICY_NAMES:
        raise ConfigError(f"policy must be one of {POLICY_NAMES}, got {name!r}")
    if name == "straightforward":
        return StraightforwardPolicy()
    if qtable_path is not None and (not learn or Path(qtable_path).exists()):
        table = QTable.load(qtable_path, config.qlearning)
    elif not learn:
        raise ConfigError("qtable_path must name a learned Q-table when learn is False, got None")
    else:
        table = QTable(config.qlearning)
    return QLearningPolicy(table, rng, learn=learn)
