"""The attention cycle engine: one control cycle = one action (sections 4.1, 4.2 and 5).

The driver (the ROS attention node, or an in-process loop) first runs the initial scan,
which settles the pre-attentional map over the whole workspace::

    while (look := ctl.next_look()) is not None:   # AttentionConfig.home_targets
        execute look, render, perceive;
        ctl.observe(rois, now, ctl.visibility(camera, pose), camera, pose)

then runs each cycle as::

    plan = ctl.begin_cycle(now)                # the policy picks the action
    if plan.goal:                              # physical action
        execute, render, perceive; ctl.observe(rois, now, visible, camera, pose)
        req = ctl.match_request()              # None when the focus is lost from view
        result = memory(req) if req else None
    elif plan.memory_request:                  # map update of a new object: store it
        result = memory(plan.memory_request)
    record = ctl.end_cycle(result, now)

An idle plan (nothing in the map to attend to) queues a new scan: the driver looks again
(``next_look``) before the next ``begin_cycle``. ``export_state`` and ``restore_state``
carry what a restarted driver needs to go on where a crashed one stopped. Exported while a
map update's STORE is out (``begin_cycle`` done, ``end_cycle`` not), the state also holds
that store: a restarted driver sends it again (``store_in_flight``; the memory answers a
store it already made with the same address) and closes its cycle with ``finish_store``,
so no store the memory made goes unrecorded.

Nothing here blocks or does I/O; the controller only keeps the state between the calls.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from roger_attention.config import AttentionConfig
from roger_attention.fsm import (
    INITIAL_STATE,
    State,
    allowed_actions,
    check_allowed,
    reward,
    transition,
)
from roger_attention.policies import Policy, QLearningPolicy
from roger_attention.spatial_map import MapChanges, MapEntry, Position, SpatialMap, VisibleFn
from roger_common.configdoc import check_live_change
from roger_common.geometry import as_point, in_view
from roger_common.types import (
    Action,
    CameraModel,
    EyePose,
    Goal,
    MatchOutcome,
    MatchResult,
    MemoryOp,
    MemoryRequest,
    Roi,
    RunCounters,
)

#: Outcome strings of a CycleRecord.
OUTCOMES: tuple[str, ...] = (
    "identified", "new", "undetermined", "stored", "mapped", "remapped", "lost", "none")
#: Goal ids of the looks of the initial scan (not control cycles) start here, far above the
#: cycles' own ids (1, 2, ...). Each look has an id of its own: with one shared id, a
#: retried look's late frame answered the next look and started a second chain of cycles.
LOOK_ID_BASE = 1 << 62
#: Format tag of ``export_state``.
STATE_FORMAT = "roger_attention_controller/1"


def _bbox(b: Sequence[int]) -> tuple[int, int, int, int]:
    x0, y0, x1, y1 = (int(v) for v in b)
    return (x0, y0, x1, y1)


def is_look(goal_id: int) -> bool:
    """True for the goal id of an initial-scan look."""
    return goal_id >= LOOK_ID_BASE


@dataclass(frozen=True)
class CyclePlan:
    """What the driver must do in this cycle.

    Attributes:
        cycle: Number of the cycle (1 for the first); an idle plan carries the number
            the next real cycle will have.
        action: The action the policy chose.
        goal: The physical action to execute (None for a map update or an idle cycle).
            Its target is the focused entry's position; for a shift, the new focus.
        memory_request: The STORE of a new object's map update, else None.
        entry_id: Entry in focus for this cycle; -1 when none.
        state: The "nim" bits the action was chosen in.
        idle: True when there is nothing to attend to (empty map): the cycle is not
            counted and the driver just calls end_cycle.
    """

    cycle: int
    action: Action
    goal: Goal | None
    memory_request: MemoryRequest | None
    entry_id: int
    state: str
    idle: bool = False


@dataclass(frozen=True)
class CycleRecord:
    """What one cycle did, for logs, plots and Table 2.

    Attributes:
        cycle: Cycle number.
        state_before: "nim" bits before the action.
        action: The action.
        state_after: "nim" bits after it.
        reward: Reward of the transition.
        td_error: TD error of the Q update; None when nothing was learnt.
        entry_id: Entry in focus; -1 when none.
        position: Its position, robot frame (None when none).
        bbox: Its freshest ROI's bounding box in the left retina (None when none).
        outcome: One of OUTCOMES. A map update is "stored" (a new object), "mapped" (a
            positive identification: an entry not mapped before) or "remapped" (an
            entry mapped before, identified and mapped again).
        address: Long-term-memory address concerned; -1 when none.
        counters: Copy of the run counters after the cycle.
        goal_id: Id of the cycle's physical goal (its convergence report carries it); 0
            for a map update.
    """

    cycle: int
    state_before: str
    action: Action
    state_after: str
    reward: float
    td_error: float | None
    entry_id: int
    position: Position | None
    bbox: tuple[int, int, int, int] | None
    outcome: str
    address: int
    counters: RunCounters
    goal_id: int = 0

    def to_dict(self) -> dict[str, Any]:
        """The record as JSON-ready data (:meth:`from_dict` reads it back)."""
        d = dataclasses.asdict(self)
        d["action"] = int(self.action)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> CycleRecord:
        """A record written by :meth:`to_dict`; ValueError/KeyError/TypeError if corrupt."""
        position, bbox = d["position"], d["bbox"]
        return cls(
            cycle=int(d["cycle"]), state_before=str(d["state_before"]),
            action=Action(int(d["action"])), state_after=str(d["state_after"]),
            reward=float(d["reward"]),
            td_error=None if d["td_error"] is None else float(d["td_error"]),
            entry_id=int(d["entry_id"]),
            position=None if position is None else as_point(position),
            bbox=None if bbox is None else _bbox(bbox),
            outcome=str(d["outcome"]), address=int(d["address"]),
            counters=RunCounters(**d["counters"]), goal_id=int(d.get("goal_id", 0)))


@dataclass
class _Pending:
    plan: CyclePlan
    state: State
    frame: int
    final_trial: bool


def eyes_still(before: EyePose, after: EyePose, camera: CameraModel) -> bool:
    """Whether the eyes moved less than one pixel between two frames: the optical axis
    turned by less than one pixel's angle (1 / focal_px) and the optical centre moved
    by less than one pixel's width at half a metre (the near edge of the workspace).
    A visual or haptic improvement leaves the eyes there; an attention shift or a look
    moves them."""
    turn = before.rotation.T @ after.rotation
    angle = math.acos(max(-1.0, min(1.0, (float(np.trace(turn)) - 1.0) / 2.0)))
    shift = float(np.linalg.norm(np.subtract(after.position, before.position)))
    return angle < 1.0 / camera.focal_px and shift < 0.5 / camera.focal_px


class AttentionController:
    """Spatial map, attention window, attention shift, FSM, policy and counters.

    Attributes:
        config: The configuration.
        policy: The straightforward or the Q-learning policy.
        rng: Randomness of the controller (reserved; the policies hold their own).
        spatial_map: The pre-attentional map.
        counters: Table 2's counters; both identities hold by construction.
        td_errors: TD error of every Q update of this run.
        focus: Entry in the attention window, None before the first shift.
    """

    def __init__(self, config: AttentionConfig, policy: Policy,
                 rng: np.random.Generator) -> None:
        """Start with an empty map, nothing in focus and state 000."""
        self.config = config
        self.policy = policy
        self.rng = rng
        self.spatial_map = SpatialMap(config.spatial_map)
        self.counters = RunCounters()
        self.td_errors: list[float] = []
        self.focus: int | None = None
        self._state = INITIAL_STATE
        self._visual_left = 0
        self._haptic_left = 0
        self._focus_address = -1
        self._focus_id = 0  # goal id of the focus's shift: memory groups its looks by it
        self._last_pose: EyePose | None = None  # the left eye's, of the last observe
        self._pending: _Pending | None = None
        self._next_goal_id = 1
        self._next_request_id = 1
        self._scan: list[Position] = list(config.scan_targets)
        self._looks = 0
        self._restored_places: list[tuple[Position, int]] = []
        # Entries mapped at some time that are still in the map (their latest position),
        # and the places of those that left it since (forgotten or vanished): what tells a
        # remap from a positive identification.
        self._ever_mapped: dict[int, Position] = {}
        self._gone_places: list[Position] = []
        self._since_new = 0  # counted cycles since the last new representation was stored
        self._restored_store: dict[str, Any] | None = None  # restore_state's store in flight

    @property
    def state(self) -> State:
        """The FSM state the next cycle starts in (``.bits`` gives the "nim" string); its
        mapping bit is read from the spatial map now."""
        self._refresh_state()
        return self._state

    # -- the initial scan ------------------------------------------------------------------
    @property
    def scanning(self) -> bool:
        """True while looks of the initial scan are left (``next_look`` gives them)."""
        return bool(self._scan)

    def next_look(self) -> Goal | None:
        """The next look of the initial scan, or None once the scan is over.

        The scan is queued at construction and after an idle plan. Each look is an
        attention shift to one of ``AttentionConfig.home_targets``, with a goal id of its
        own (``is_look``); its frame goes to :meth:`observe` like any other. When the scan
        ends, places mapped before a restart (:meth:`restore_state`) are mapped again.
        """
        if not self._scan:
            if self._restored_places:
                for entry_id in self.spatial_map.restore_mapped(self._restored_places):
                    self._ever_mapped[entry_id] = self.spatial_map.entries[entry_id].position
                radius = self.config.spatial_map.association_radius
                self._gone_places += [  # places mapped before the restart not seen again
                    p for p, _ in self._restored_places
                    if not any(math.dist(p, q) <= radius for q in self._ever_mapped.values())]
                self._restored_places = []
            return None
        self._looks += 1
        return Goal(LOOK_ID_BASE + self._looks, Action.ATTENTION_SHIFT, self._scan.pop(0))

    def visibility(self, camera: CameraModel | None, pose: EyePose | None) -> VisibleFn | None:
        """Whether a map place is in view of the eye ``pose`` (None when either is unknown).

        A place must project ``visibility_margin`` of the retina's width inside its edge:
        regions cut by the edge are not reliably seen, and must not count as vanished.
        """
        if camera is None or pose is None:
            return None
        margin = self.config.visibility_margin * camera.width
        return lambda p: in_view(camera, pose, p, margin)

    # -- resuming after a restart -----------------------------------------------------------
    def reconfigure(self, config: AttentionConfig) -> None:
        """Take a new configuration that differs only in fields marked live (the Q-learning
        exploration ``qlearning.epsilon``, the map's ``spatial_map.interest_rate``); the
        next cycle uses it.

        Raises:
            ValueError: Another field differs (restart to change it).
        """
        check_live_change(self.config, config)
        self.config = config
        self.spatial_map.config = config.spatial_map
        if isinstance(self.policy, QLearningPolicy):
            self.policy.epsilon = config.qlearning.epsilon

    def export_state(self) -> dict[str, Any]:
        """What a restarted controller needs to go on (JSON-ready): counters, next ids,
        the policy's learnt state and the mapped places."""
        return {
            "format": STATE_FORMAT, "policy": self.policy.name,
            "counters": dataclasses.asdict(self.counters),
            "next_goal_id": self._next_goal_id, "next_request_id": self._next_request_id,
            "looks": self._looks, "policy_state": self.policy.state_dict(),
            "mapped": [{"position": list(p), "address": int(a)}
                       for p, a in self.spatial_map.mapped_places()],
            "mapped_before": [list(p) for p in self._places_mapped_before()],
            "cycles_since_new": self._since_new,
            "store_in_flight": self._store_in_flight(),
        }

    def _store_in_flight(self) -> dict[str, Any] | None:
        """The open cycle's STORE and what closing it needs (JSON-ready), or None."""
        if self._restored_store is not None:
            return self._restored_store
        pending = self._pending
        if pending is None or pending.plan.memory_request is None:
            return None
        plan, request = pending.plan, pending.plan.memory_request
        entry = self.spatial_map.get(plan.entry_id)
        if entry is None:
            return None
        after = transition(pending.state, Action.MAP_UPDATE, None, True)
        allowed = allowed_actions(after, self._visual_left, self._haptic_left,
                                  has_focus=self.focus is not None)
        return {"request_id": request.request_id, "features": request.features.tolist(),
                "known": request.known.tolist(), "focus_id": request.focus_id,
                "cycle": plan.cycle, "state": pending.state.bits, "entry_id": plan.entry_id,
                "position": list(entry.position), "bbox": list(_bbox(entry.roi.bbox)),
                "allowed_after": [int(a) for a in allowed]}

    def restore_state(self, state: dict[str, Any]) -> None:
        """Go on from an ``export_state`` of a controller that stopped (a crash).

        Counters and the policy's state are taken back. Goal and request ids go on after
        the saved ones, skipping one each: the cycle in flight when the driver stopped may
        have used them. The places mapped then are mapped again at the end of the next
        initial scan (the map itself is rebuilt by looking); those mapped before and
        unmapped then still make an identification there a remap.

        Raises:
            ValueError: The state is not one of this format and policy, or is corrupt.
        """
        try:
            if state.get("format") != STATE_FORMAT or state["policy"] != self.policy.name:
                raise ValueError(f"format {state.get('format')!r}, policy "
                                 f"{state.get('policy')!r}")
            counters = RunCounters(**state["counters"])
            goal_id, request_id = int(state["next_goal_id"]), int(state["next_request_id"])
            looks = int(state["looks"])
            places = [(tuple(float(v) for v in p["position"]), int(p["address"]))
                      for p in state["mapped"]]
            if any(len(p) != 3 for p, _ in places):
                raise ValueError("a mapped place is not an (x, y, z) position")
            before = [as_point(p) for p in state.get("mapped_before", [])]
            since_new = int(state.get("cycles_since_new", 0))
            store = state.get("store_in_flight")
            if store is not None:
                store = dict(store)
                store["state"] = State.from_bits(str(store["state"])).bits
                store["request_id"], store["cycle"] = int(store["request_id"]), \
                    int(store["cycle"])
                if len(store["position"]) != 3 or len(store["features"]) != len(
                        store["known"]):
                    raise ValueError("the store in flight is malformed")
            self.policy.load_state_dict(state["policy_state"])
        except (KeyError, TypeError, AttributeError) as exc:
            raise ValueError(f"corrupt attention state ({exc!r})") from None
        self.counters = counters
        self._next_goal_id, self._next_request_id = goal_id + 1, request_id + 1
        self._looks = looks
        self._restored_places = places  # type: ignore[assignment]
        self._gone_places = before
        self._ever_mapped = {}
        self._since_new = since_new
        self._restored_store = store

    @property
    def store_in_flight(self) -> MemoryRequest | None:
        """The map update's STORE that the stopped controller had sent when it stopped
        (restored by ``restore_state``): send it again, then close its cycle with
        ``finish_store``. None when there is none."""
        s = self._restored_store
        if s is None:
            return None
        return MemoryRequest(s["request_id"], MemoryOp.STORE,
                             np.asarray(s["features"], dtype=np.float64),
                             np.asarray(s["known"], dtype=bool), focus_id=int(s["focus_id"]))

    def finish_store(self, result: MatchResult | None) -> CycleRecord:
        """Close the cycle of ``store_in_flight`` with the memory's answer, as ``end_cycle``
        would have: counters, reward and Q update, and the place mapped with the stored
        address (at the end of the next scan, with the other restored places).

        Raises:
            RuntimeError: No store is in flight.
        """
        s, self._restored_store = self._restored_store, None
        if s is None:
            raise RuntimeError("finish_store called without a store in flight")
        state = State.from_bits(s["state"])
        after = transition(state, Action.MAP_UPDATE, None, True)
        address = result.address if result is not None and result.address >= 0 else -1
        self._count(Action.MAP_UPDATE, "stored")
        r = reward(state, Action.MAP_UPDATE, after, self.config.rewards)
        td = self.policy.update(state, Action.MAP_UPDATE, r, after, False,
                                tuple(Action(int(a)) for a in s["allowed_after"]))
        if td is not None:
            self.td_errors.append(td)
        position = as_point(s["position"])
        self._restored_places.append((position, address))
        return CycleRecord(
            cycle=s["cycle"], state_before=state.bits, action=Action.MAP_UPDATE,
            state_after=after.bits, reward=r, td_error=td, entry_id=int(s["entry_id"]),
            position=position, bbox=_bbox(s["bbox"]), outcome="stored", address=address,
            counters=dataclasses.replace(self.counters), goal_id=0)

    @property
    def cycles_since_new(self) -> int:
        """Counted cycles since the last new representation (a new object stored in the
        long-term memory); all cycles so far when none was."""
        return self._since_new

    def complete(self, stable_cycles: int) -> bool:
        """The robot's own end of an inspection ("until no more new representations were
        detected", section 5): no new representation for ``stable_cycles`` cycles and no
        unmapped entry left in a map that holds something. Nothing here reads the ground
        truth; whether every object was visited is for the evaluation to judge afterwards.
        """
        return (self._since_new >= stable_cycles and len(self.spatial_map) > 0
                and self.spatial_map.all_mapped())

    @property
    def in_cycle(self) -> bool:
        """True between begin_cycle and end_cycle."""
        return self._pending is not None

    def mapped_positions(self) -> list[Position]:
        """Positions of every mapped entry (perception lowers their activation)."""
        return self.spatial_map.mapped_positions()

    def allowed(self) -> tuple[Action, ...]:
        """Actions the FSM allows in the state the next cycle starts in."""
        self._refresh_state()
        return self._allowed()

    def _allowed(self) -> tuple[Action, ...]:
        return allowed_actions(self._state, self._visual_left, self._haptic_left,
                               has_focus=self.focus is not None)

    def observe(self, rois: Sequence[Roi], now: float, visible: VisibleFn | None = None,
                camera: CameraModel | None = None, pose: EyePose | None = None
                ) -> MapChanges:
        """Merge one frame's ROIs into the spatial map (see SpatialMap.update).

        ``camera`` and ``pose`` (the left retina's, as for :meth:`visibility`) tell whether
        the eyes stood still since the previous frame (:func:`eyes_still`); unknown counts
        as moved.
        """
        still = (camera is not None and pose is not None and self._last_pose is not None
                 and eyes_still(self._last_pose, pose, camera))
        self._last_pose = pose if camera is not None else None
        changes = self.spatial_map.update(rois, now, visible, still=still)
        if self.focus is not None and self.focus not in self.spatial_map:
            self.focus = None
        self._track_mapped()
        return changes

    def begin_cycle(self, now: float) -> CyclePlan:
        """Let the policy choose this cycle's action and say what to execute.

        Raises:
            RuntimeError: A cycle is already open.
            IllegalActionError: The policy chose an action the FSM does not allow.
        """
        if self._pending is not None:
            raise RuntimeError("begin_cycle called again before end_cycle")
        self.spatial_map.advance(now)
        self._refresh_state()
        state = self._state
        allowed = self._allowed()
        action = Action(self.policy.select_action(state, allowed))
        check_allowed(action, allowed, state)
        cycle = self.counters.cycles + 1
        goal: Goal | None = None
        store: MemoryRequest | None = None
        if action is Action.ATTENTION_SHIFT:
            target = self.spatial_map.select_focus(exclude=self.focus)
            if target is None:
                plan = CyclePlan(cycle, action, None, None, -1, state.bits, idle=True)
                self._pending = _Pending(plan, state, self.spatial_map.frame, False)
                return plan
            self.focus = target
            self.spatial_map.focus(target, now)
            self._visual_left = self.config.visual_trials
            self._haptic_left = self.config.haptic_trials
            self._focus_address = -1
        elif action is Action.VISUAL_IMPROVEMENT:
            self._visual_left -= 1
        elif action is Action.HAPTIC_IMPROVEMENT:
            self._haptic_left -= 1
        entry = self.spatial_map.get(self.focus)
        assert entry is not None  # allowed_actions gives only a shift without a focus
        if action is Action.MAP_UPDATE:
            if state.novelty:
                store = MemoryRequest(self._take_request_id(), MemoryOp.STORE,
                                      entry.features.copy(), entry.known.copy(),
                                      focus_id=self._focus_id)
        else:
            goal = Goal(self._next_goal_id, action, entry.position)
            self._next_goal_id += 1
            if action is Action.ATTENTION_SHIFT:
                self._focus_id = goal.goal_id
        final = self._visual_left <= 0 and self._haptic_left <= 0
        plan = CyclePlan(cycle, action, goal, store, entry.entry_id, state.bits)
        self._pending = _Pending(plan, state, self.spatial_map.frame, final)
        return plan

    def match_request(self) -> MemoryRequest | None:
        """MATCH of the focused entry's features after this cycle's physical action.

        Returns:
            The request (``final_trial`` set when no improvement trial is left), or None
            outside a physical action's cycle or when no ROI of the focused entry was
            observed since begin_cycle (the object is lost from view).
        """
        pending = self._pending
        if pending is None or pending.plan.goal is None:
            return None
        entry = self.spatial_map.get(pending.plan.entry_id)
        if entry is None or entry.last_frame <= pending.frame:
            return None
        return MemoryRequest(self._take_request_id(), MemoryOp.MATCH, entry.features.copy(),
                             entry.known.copy(), final_trial=pending.final_trial,
                             focus_id=self._focus_id)

    def end_cycle(self, result: MatchResult | None, now: float) -> CycleRecord:
        """Close the cycle: FSM transition, reward, Q update, counters, interest.

        Args:
            result: The memory's answer to this cycle's match (physical action) or store
                (map update of a new object); None when there was none or the focus was
                lost.
            now: Simulated time at the end of the cycle.

        Raises:
            RuntimeError: No cycle is open.
        """
        pending = self._pending
        if pending is None:
            raise RuntimeError("end_cycle called without begin_cycle")
        self._pending = None
        self.spatial_map.advance(now)
        plan, state = pending.plan, pending.state
        if plan.idle:
            self._scan = list(self.config.scan_targets)  # nothing to attend to: look again
            return self._record(plan, state, state, 0.0, None, "none", -1)
        entry = self.spatial_map.get(plan.entry_id)
        forgotten: MapEntry | None = None
        if plan.action is Action.MAP_UPDATE:
            outcome, address = self._map_update(state, result)
            next_state = transition(state, plan.action, None, True)
        else:
            matched = self._matched_outcome(pending, result)
            outcome = "lost" if matched is None else matched.name.lower()
            if matched is None and entry is not None and entry.last_frame <= pending.frame:
                # The eyes were moved onto the entry's place and no ROI was found there:
                # a spurious region or an object that went away. Forget the place, so the
                # policy shifts on instead of improving nothing.
                self.spatial_map.forget(entry.entry_id)
                self._track_mapped()
                forgotten, entry = entry, None
            address = result.address if matched is MatchOutcome.IDENTIFIED and result else -1
            if matched is MatchOutcome.IDENTIFIED:
                self._focus_address = address
            if entry is not None and entry.mapped and self._contradicts(entry.address, matched,
                                                                        address):
                self.spatial_map.clear_mapping(entry.entry_id)
            mapped = entry is not None and entry.mapped
            next_state = transition(state, plan.action, matched, mapped)
        self._count(plan.action, outcome)
        r = reward(state, plan.action, next_state, self.config.rewards)
        self._state = next_state
        if self.focus is not None and self.focus not in self.spatial_map:
            self.focus = None
        # Never terminal (docs/attention.md, the MDP): a shift is worth what the state it
        # lands in is worth, a map update what follows it; the run's end only truncates.
        td = self.policy.update(state, plan.action, r, next_state, False, self._allowed())
        if td is not None:
            self.td_errors.append(td)
        if self.focus is not None:
            self.spatial_map.keep_focus(self.focus, now)
        return self._record(plan, state, next_state, r, td, outcome, address, forgotten)

    def _matched_outcome(self, pending: _Pending,
                         result: MatchResult | None) -> MatchOutcome | None:
        entry = self.spatial_map.get(pending.plan.entry_id)
        if result is None or entry is None or entry.last_frame <= pending.frame:
            return None
        outcome = MatchOutcome(result.outcome)
        if outcome is MatchOutcome.NEW and not pending.final_trial:
            # Novelty is set only when no match occurred after all trials (section 4.2).
            return MatchOutcome.UNDETERMINED
        return outcome

    @staticmethod
    def _contradicts(mapped_address: int, outcome: MatchOutcome | None, address: int) -> bool:
        # A mapped entry that memory now calls new, or identifies as another object, holds a
        # different object than the one mapped: the map must follow.
        if outcome is MatchOutcome.NEW:
            return True
        return (outcome is MatchOutcome.IDENTIFIED and mapped_address >= 0 and address >= 0
                and address != mapped_address)

    def _map_update(self, state: State, result: MatchResult | None) -> tuple[str, int]:
        entry = self.spatial_map.get(self.focus)
        again = entry is not None and self._mapped_before(entry)
        if state.novelty:
            address = result.address if result is not None and result.address >= 0 else -1
            outcome = "stored"
        else:
            address = self._focus_address
            outcome = "remapped" if again else "mapped"
        if entry is not None:
            self.spatial_map.set_mapped(entry.entry_id, address)
            self._ever_mapped[entry.entry_id] = entry.position
        return outcome, address

    def _mapped_before(self, entry: MapEntry) -> bool:
        """Whether the entry, or the place it stands at, was mapped before.

        The entry itself was, if it lost its mapping since (it drifted, or a match
        contradicted it). Its place was, if an entry mapped there left the map (forgotten
        or vanished) and this one settled within the association radius of where that one
        was last seen: that place is taken, so it makes one remap at most.
        """
        if entry.entry_id in self._ever_mapped:
            return True
        radius = self.config.spatial_map.association_radius
        near = [(math.dist(p, entry.position), k) for k, p in enumerate(self._gone_places)]
        near = [(d, k) for d, k in near if d <= radius]
        if not near:
            return False
        del self._gone_places[min(near)[1]]
        return True

    def _track_mapped(self) -> None:
        """Follow the entries mapped at some time; keep the places of those that left."""
        for entry_id, position in list(self._ever_mapped.items()):
            entry = self.spatial_map.get(entry_id)
            if entry is None:
                del self._ever_mapped[entry_id]
                self._gone_places.append(position)
            else:
                self._ever_mapped[entry_id] = entry.position

    def _places_mapped_before(self) -> list[Position]:
        """Places mapped once and not mapped now (a restart keeps them)."""
        unmapped = [p for eid, p in self._ever_mapped.items()
                    if not self.spatial_map.entries[eid].mapped]
        return [*self._gone_places, *unmapped]

    def _count(self, action: Action, outcome: str) -> None:
        c = self.counters
        c.cycles += 1
        self._since_new = 0 if outcome == "stored" else self._since_new + 1
        if action is Action.ATTENTION_SHIFT:
            c.attention_shifts += 1
        elif action is Action.VISUAL_IMPROVEMENT:
            c.visual_improvements += 1
        elif action is Action.HAPTIC_IMPROVEMENT:
            c.haptic_improvements += 1
        else:
            # Allowed only with novelty or identity 1, so Table 2's second identity holds.
            c.map_updates += 1
            if outcome == "stored":
                c.new_objects += 1
            elif outcome == "remapped":
                c.remaps += 1
            else:
                c.positive_identifications += 1

    def _refresh_state(self) -> None:
        entry = self.spatial_map.get(self.focus)
        if entry is None:
            self._state = INITIAL_STATE
        elif self._state.mapping != int(entry.mapped):
            self._state = State(self._state.novelty, self._state.identity, int(entry.mapped))

    def _take_request_id(self) -> int:
        rid = self._next_request_id
        self._next_request_id += 1
        return rid

    def _record(self, plan: CyclePlan, before: State, after: State, r: float,
                td: float | None, outcome: str, address: int,
                forgotten: MapEntry | None = None) -> CycleRecord:
        entry = self.spatial_map.get(plan.entry_id) or forgotten
        return CycleRecord(
            cycle=plan.cycle,
            state_before=before.bits, action=plan.action, state_after=after.bits, reward=r,
            td_error=td, entry_id=plan.entry_id,
            position=entry.position if entry is not None else None,
            bbox=_bbox(entry.roi.bbox) if entry is not None else None,
            outcome=outcome, address=address, counters=dataclasses.replace(self.counters),
            goal_id=plan.goal.goal_id if plan.goal is not None else 0)
