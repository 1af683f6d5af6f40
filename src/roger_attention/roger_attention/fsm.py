"""The finite state machine of Figure 3 (section 4.2): states, allowed actions, rewards.

A state is three bits of the ROI in focus: novelty, identity and mapping ("nim").
Novelty and identity are 0 just after an attention shift, before the match; the match that
follows every physical action sets identity on an identification and novelty when no match
occurred after all trials. They are never both 1, which leaves the six states of Figure 3.
The mapping bit is read from the spatial-map entry in focus.

No transition is terminal: inspection never ends (interest keeps attention moving, section
5), so what follows an attention shift or a map update is valued like anything else
(docs/attention.md states the whole MDP).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from roger_attention.config import RewardConfig
from roger_common.errors import RogerError
from roger_common.types import Action, MatchOutcome


class IllegalActionError(RogerError, ValueError):
    """An action was asked for in a state where the FSM does not allow it."""


@dataclass(frozen=True, order=True)
class State:
    """The perceptual state of section 4.2.

    Attributes:
        novelty: 1 when the ROI holds a new object (no match after all trials).
        identity: 1 when the associative memory matched the ROI.
        mapping: Mapping status of the spatial-map entry in focus.
    """

    novelty: int
    identity: int
    mapping: int

    def __post_init__(self) -> None:
        for name in ("novelty", "identity", "mapping"):
            if getattr(self, name) not in (0, 1):
                raise ValueError(f"State.{name} must be 0 or 1, got {getattr(self, name)!r}")
        if self.novelty and self.identity:
            raise ValueError("State: novelty and identity cannot both be 1")

    @property
    def bits(self) -> str:
        """The "nim" bit string of Figure 3, e.g. "010"."""
        return f"{self.novelty}{self.identity}{self.mapping}"

    @property
    def decided(self) -> bool:
        """True when the match concluded (identity or novelty is 1)."""
        return bool(self.novelty or self.identity)

    @property
    def index(self) -> int:
        """Row of this state in a Q-table (position in ``STATES``)."""
        return STATES.index(self)

    @classmethod
    def from_bits(cls, bits: str) -> State:
        """Parse a "nim" bit string such as "100".

        Raises:
            ValueError: When the string is not three bits of a reachable state.
        """
        if len(bits) != 3 or any(c not in "01" for c in bits):
            raise ValueError(f"a state is three bits 'nim', got {bits!r}")
        return cls(int(bits[0]), int(bits[1]), int(bits[2]))

    def __str__(self) -> str:
        return self.bits


#: The six reachable states of Figure 3, in Q-table row order.
STATES: tuple[State, ...] = tuple(
    State(n, i, m) for n, i in ((0, 0), (0, 1), (1, 0)) for m in (0, 1)
)
#: Where a run starts: nothing matched, nothing mapped.
INITIAL_STATE = State(0, 0, 0)
#: The four actions in Q-table column order.
ACTIONS: tuple[Action, ...] = tuple(Action)


def allowed_actions(state: State, visual_left: int = 1, haptic_left: int = 1,
                    has_focus: bool = True) -> tuple[Action, ...]:
    """The actions the FSM allows in ``state``.

    An attention shift is always allowed. Improvements are allowed while the match is
    undetermined and trials are left. A map update is allowed only when identity or
    novelty is 1 and the entry is not mapped yet: this is what makes Table 2's
    map updates == positive identifications + new objects hold by construction.

    Args:
        state: Current state.
        visual_left: Visual improvements left for the ROI in focus.
        haptic_left: Haptic improvements left for the ROI in focus.
        has_focus: False when no ROI is in focus (start, or the focus vanished): then only
            an attention shift makes sense.

    Returns:
        Allowed actions in ``ACTIONS`` order.
    """
    if not has_focus:
        return (Action.ATTENTION_SHIFT,)
    out = [Action.ATTENTION_SHIFT]
    if not state.decided:
        if visual_left > 0:
            out.append(Action.VISUAL_IMPROVEMENT)
        if haptic_left > 0:
            out.append(Action.HAPTIC_IMPROVEMENT)
    elif not state.mapping:
        out.append(Action.MAP_UPDATE)
    return tuple(out)


def possible_actions(state: State) -> tuple[Action, ...]:
    """The actions possible in ``state`` with a full trial budget (the set A of section 2)."""
    return allowed_actions(state)


def match_bits(outcome: MatchOutcome | None) -> tuple[int, int]:
    """(novelty, identity) after a match; None (object lost from view) counts as undetermined.

    Cases a-c of section 4.2: IDENTIFIED -> (0, 1), NEW -> (1, 0), UNDETERMINED -> (0, 0).
    """
    if outcome is MatchOutcome.IDENTIFIED:
        return 0, 1
    if outcome is MatchOutcome.NEW:
        return 1, 0
    return 0, 0


def transition(state: State, action: Action, outcome: MatchOutcome | None,
               mapped: bool) -> State:
    """The state after ``action``.

    Args:
        state: State before the action.
        action: The action of this cycle.
        outcome: The match after a physical action (ignored for a map update).
        mapped: Mapping status of the entry in focus after the action (for a shift, the
            new focus; ignored for a map update, which sets it).

    Returns:
        The next state.

    Raises:
        IllegalActionError: A map update when neither identity nor novelty is 1, or on an
            entry already mapped.
    """
    if action is Action.MAP_UPDATE:
        if not state.decided or state.mapping:
            raise IllegalActionError(f"map update not allowed in state {state.bits}")
        return State(state.novelty, state.identity, 1)
    novelty, identity = match_bits(outcome)
    return State(novelty, identity, int(bool(mapped)))


def reward(state: State, action: Action, next_state: State, rewards: RewardConfig) -> float:
    """Reward of a transition; only the map updates 100->101 and 010->011 earn one.

    Circumstance (a) (an un-mapped position) is part of both rewarded transitions,
    (b) (a new object) of 100->101 and (c) (a positive identification) of 010->011.
    """
    if action is not Action.MAP_UPDATE:
        return 0.0
    if state.bits == "100" and next_state.bits == "101":
        return rewards.unmapped + rewards.new_object
    if state.bits == "010" and next_state.bits == "011":
        return rewards.unmapped + rewards.identification
    return 0.0


def check_allowed(action: Action, allowed: Sequence[Action], state: State) -> None:
    """Raise IllegalActionError naming the state when ``action`` is not in ``allowed``."""
    if action not in allowed:
        names = ", ".join(a.name for a in allowed)
        raise IllegalActionError(
            f"action {Action(action).name} not allowed in state {state.bits} (allowed: {names})")
