"""Tabular Q-learning over the six states and four actions of Figure 3 (section 4.2).

Q(s, a) += alpha (r + gamma max_{a' in A(s')} Q(s', a') - Q(s, a))   (section 2)

with the paper's constant alpha, or (``QLearningConfig.alpha_schedule`` "visits") a step
size alpha / (1 + n(s, a) / alpha_k) that decays with the pair's earlier updates n(s, a).

The table is saved as JSON through roger_common.atomic, so a crash leaves either the old
file or the new one.
"""

from __future__ import annotations

import dataclasses
import json
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from roger_attention.config import QLearningConfig
from roger_attention.fsm import ACTIONS, STATES, State, possible_actions
from roger_common.atomic import atomic_write_bytes
from roger_common.errors import ConfigError, MemoryFileError
from roger_common.types import Action

#: Tag written into every Q-table file and checked on load.
FILE_FORMAT = "roger-attention-qtable/1"


class QTable:
    """Q-values of every (state, action) pair, with the TD error of every update kept.

    Attributes:
        config: Learning rate, discount, exploration, initial value.
        q: Array of shape (len(STATES), len(ACTIONS)).
        visits: Updates of each (state, action) so far, same shape (saved with the table:
            a table trained further goes on with its step sizes).
        td_errors: TD error of each update, in order.
    """

    def __init__(self, config: QLearningConfig | None = None) -> None:
        """Create a table with every Q(s, a) at ``config.initial_q``."""
        self.config = config if config is not None else QLearningConfig()
        self.q = np.full((len(STATES), len(ACTIONS)), self.config.initial_q, dtype=float)
        self.visits = np.zeros((len(STATES), len(ACTIONS)), dtype=np.int64)
        self.td_errors: list[float] = []

    def step_size(self, state: State, action: Action) -> float:
        """The step size of the next update of (s, a) (``QLearningConfig.alpha_schedule``)."""
        cfg = self.config
        if cfg.alpha_schedule == "constant":
            return cfg.alpha
        return cfg.alpha / (1.0 + self.visits[state.index, int(action)] / cfg.alpha_k)

    def value(self, state: State, action: Action) -> float:
        """Q(s, a)."""
        return float(self.q[state.index, int(action)])

    def best_value(self, state: State, allowed: Sequence[Action] | None = None) -> float:
        """max over a' in ``allowed`` (default: the actions possible in ``state``) of Q(s, a')."""
        acts = possible_actions(state) if allowed is None else allowed
        return float(max(self.q[state.index, int(a)] for a in acts))

    def greedy_actions(self, state: State, allowed: Sequence[Action]) -> list[Action]:
        """All allowed actions of largest Q(s, a) (several when tied)."""
        if not allowed:
            raise ValueError(f"no allowed action in state {state.bits}")
        values = np.array([self.q[state.index, int(a)] for a in allowed])
        best = values.max()
        return [Action(a) for a, v in zip(allowed, values, strict=True) if v == best]

    def select_action(self, state: State, rng: np.random.Generator,
                      allowed: Sequence[Action] | None = None,
                      epsilon: float | None = None) -> Action:
        """Epsilon-greedy choice with random tie-breaks.

        Args:
            state: Current state.
            rng: The only source of randomness.
            allowed: Actions to choose from (default: those possible in ``state``).
            epsilon: Exploration probability (default: ``config.epsilon``; 0 is greedy).

        Returns:
            The chosen action.
        """
        acts = list(possible_actions(state) if allowed is None else allowed)
        eps = self.config.epsilon if epsilon is None else epsilon
        if not acts:
            raise ValueError(f"no allowed action in state {state.bits}")
        if eps > 0.0 and rng.random() < eps:
            return Action(acts[int(rng.integers(len(acts)))])
        best = self.greedy_actions(state, acts)
        return best[int(rng.integers(len(best)))] if len(best) > 1 else best[0]

    def update(self, state: State, action: Action, reward: float, next_state: State,
               terminated: bool, next_allowed: Sequence[Action] | None = None) -> float:
        """One Q-learning update; returns and keeps its TD error.

        Args:
            state: s.
            action: a.
            reward: r.
            next_state: s'.
            terminated: True when s' ends the episode (its value is then 0).
            next_allowed: The set A of actions possible in s' (default: with a full
                trial budget).

        Returns:
            The TD error r + gamma max Q(s', a') - Q(s, a) before the update.
        """
        target = reward
        if not terminated:
            target += self.config.gamma * self.best_value(next_state, next_allowed)
        i, j = state.index, int(action)
        td = float(target - self.q[i, j])
        self.q[i, j] += self.step_size(state, action) * td  # section 2's update rule
        self.visits[i, j] += 1
        self.td_errors.append(td)
        return td

    def to_dict(self) -> dict[str, object]:
        """The table as plain JSON-ready data."""
        return {
            "format": FILE_FORMAT,
            "states": [s.bits for s in STATES],
            "actions": [a.name for a in ACTIONS],
            "alpha": self.config.alpha,
            "gamma": self.config.gamma,
            "epsilon": self.config.epsilon,
            "initial_q": self.config.initial_q,
            "alpha_schedule": self.config.alpha_schedule,
            "alpha_k": self.config.alpha_k,
            "updates": len(self.td_errors),
            "q": self.q.tolist(),
            "visits": self.visits.tolist(),
        }

    def save(self, path: str | os.PathLike[str], durable: bool = True) -> None:
        """Write the table to ``path`` atomically (JSON; ``durable``: see atomic_write_bytes)."""
        data = json.dumps(self.to_dict(), indent=1).encode("utf-8")
        atomic_write_bytes(path, data, durable=durable)

    @classmethod
    def load(cls, path: str | os.PathLike[str],
             config: QLearningConfig | None = None) -> QTable:
        """Read a table written by ``save``.

        Args:
            path: The file.
            config: Learning parameters for further training (default: those in the file).
                The step-size schedule (``alpha_schedule``, ``alpha_k``) is the table's
                own, saved with its visit counts: a file that names one keeps it.

        Raises:
            MemoryFileError: The file is missing, not JSON, or not a Q-table of these
                states and actions; the message names the file.
        """
        p = Path(path)
        try:
            raw = json.loads(p.read_bytes().decode("utf-8"))
        except FileNotFoundError as exc:
            raise MemoryFileError(f"{p}: Q-table file not found") from exc
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise MemoryFileError(f"{p}: not a readable Q-table file ({exc})") from exc
        if not isinstance(raw, dict) or raw.get("format") != FILE_FORMAT:
            raise MemoryFileError(f"{p}: not a Q-table file (expected format {FILE_FORMAT})")
        if raw.get("states") != [s.bits for s in STATES] or \
                raw.get("actions") != [a.name for a in ACTIONS]:
            raise MemoryFileError(f"{p}: Q-table states/actions do not match this FSM")
        try:
            q = np.asarray(raw["q"], dtype=float)
            # Tables written before the step-size schedule existed: constant, no visits.
            visits = np.asarray(raw.get("visits", np.zeros_like(q)), dtype=np.int64)
            if config is None:
                config = QLearningConfig(
                    alpha=raw["alpha"], gamma=raw["gamma"], epsilon=raw["epsilon"],
                    initial_q=raw["initial_q"],
                    alpha_schedule=raw.get("alpha_schedule", "constant"),
                    alpha_k=raw.get("alpha_k", QLearningConfig.alpha_k))
            elif "alpha_schedule" in raw:
                config = dataclasses.replace(config, alpha_schedule=raw["alpha_schedule"],
                                             alpha_k=raw.get("alpha_k", config.alpha_k))
        except (KeyError, TypeError, ValueError, ConfigError) as exc:
            raise MemoryFileError(f"{p}: corrupt Q-table ({exc})") from exc
        if q.shape != (len(STATES), len(ACTIONS)) or not np.all(np.isfinite(q)):
            raise MemoryFileError(
                f"{p}: Q-values must be a finite {len(STATES)}x{len(ACTIONS)} table")
        if visits.shape != q.shape or np.any(visits < 0):
            raise MemoryFileError(f"{p}: visits must be a {len(STATES)}x{len(ACTIONS)} "
                                  f"table of counts >= 0")
        table = cls(config)
        table.q = q
        table.visits = visits
        return table
