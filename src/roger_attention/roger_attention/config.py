"""Configuration of the attentional control core: frozen dataclasses checked on creation.

Every value that the paper fixes is the default here (alpha 0.5, gamma 0.1 of section 2);
every value it leaves open is documented in docs/attention.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from roger_common.errors import ConfigError

#: Names accepted by ``AttentionConfig.policy`` and ``make_policy``.
POLICY_NAMES: tuple[str, ...] = ("straightforward", "qlearning")
#: The initial scan's fixation points, flattened x, y, z triples (robot frame, m): five looks
#: from far left to far right (bearings about +-60, +-28 and 0 degrees) that settle the
#: pre-attentional map over the whole workspace before the first cycle.
HOME_TARGETS: tuple[float, ...] = (0.45, 0.7, 0.0, 0.75, 0.4, 0.0, 0.9, 0.0, 0.0,
                                   0.75, -0.4, 0.0, 0.45, -0.7, 0.0)


def _check_finite(owner: str, name: str, value: float) -> None:
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
        raise ConfigError(f"{owner}.{name} must be a finite number, got {value!r}")


def _check_range(owner: str, name: str, value: float, low: float, high: float,
                 low_open: bool = False) -> None:
    _check_finite(owner, name, value)
    too_low = value <= low if low_open else value < low
    if too_low or value > high:
        left = "(" if low_open else "["
        raise ConfigError(f"{owner}.{name} must be in {left}{low}, {high}], got {value!r}")


def _check_count(owner: str, name: str, value: int, low: int = 0) -> None:
    if not isinstance(value, int) or isinstance(value, bool) or value < low:
        raise ConfigError(f"{owner}.{name} must be an integer >= {low}, got {value!r}")


@dataclass(frozen=True)
class RewardConfig:
    """Reward magnitudes of the three circumstances of section 4.2.

    Rewards are only given to the map updates 100->101 and 010->011. Circumstance (a),
    an un-mapped position found, is part of both; (b) adds for a new object, (c) for a
    positive identification. So r(100->101) = unmapped + new_object and
    r(010->011) = unmapped + identification.

    Attributes:
        unmapped: Circumstance (a), an un-mapped position of the pre-attentional map.
        new_object: Circumstance (b), an object without representation in memory.
        identification: Circumstance (c), a positive identification.
    """

    unmapped: float = 1.0
    new_object: float = 0.5
    identification: float = 1.0

    def __post_init__(self) -> None:
        for name in ("unmapped", "new_object", "identification"):
            _check_range("RewardConfig", name, getattr(self, name), 0.0, 1e6)


#: Step-size schedules of QLearningConfig.alpha_schedule.
ALPHA_SCHEDULES: tuple[str, ...] = ("constant", "visits")


@dataclass(frozen=True)
class QLearningConfig:
    """Tabular Q-learning of section 4.2.

    Attributes:
        alpha: Learning rate (the paper's 0.5); with ``alpha_schedule`` "visits", the
            step size of a pair's first update.
        gamma: Discount factor (the paper's 0.1).
        epsilon: Exploration probability of the epsilon-greedy choice while learning.
        initial_q: Value of every Q(s, a) of a fresh table.
        alpha_schedule: "constant" (the paper's: every update steps by ``alpha``) or
            "visits": the n-th update of a pair (s, a) steps by alpha / (1 + n / alpha_k),
            n counted from 0, a step size that decays with the pair's visits (the sum of
            the steps diverges and that of their squares converges, as tabular Q-learning's
            convergence asks) so that the table settles.
        alpha_k: Visits of a pair over which the "visits" step size halves.
    """

    alpha: float = 0.5
    gamma: float = 0.1
    epsilon: float = field(default=0.1, metadata={"live": True})
    initial_q: float = 0.0
    alpha_schedule: str = "constant"
    alpha_k: float = 20.0

    def __post_init__(self) -> None:
        _check_range("QLearningConfig", "alpha", self.alpha, 0.0, 1.0, low_open=True)
        _check_range("QLearningConfig", "gamma", self.gamma, 0.0, 1.0)
        _check_range("QLearningConfig", "epsilon", self.epsilon, 0.0, 1.0)
        _check_range("QLearningConfig", "initial_q", self.initial_q, -1e6, 1e6)
        if self.alpha_schedule not in ALPHA_SCHEDULES:
            raise ConfigError(f"QLearningConfig.alpha_schedule must be one of "
                              f"{', '.join(ALPHA_SCHEDULES)}, got {self.alpha_schedule!r}")
        _check_range("QLearningConfig", "alpha_k", self.alpha_k, 0.0, 1e9, low_open=True)


@dataclass(frozen=True)
class SpatialMapConfig:
    """The pre-attentional (spatial) map of section 5.

    Attributes:
        association_radius: A ROI within this distance (m) of an entry is that entry.
        moved_threshold: An entry whose position drifted this far (m) from where it was
            mapped has moved: its mapping status is cleared so that it is mapped again.
        vanish_frames: An entry whose position is in view but that no ROI matched in this
            many consecutive frames has vanished and is removed.
        interest_rate: Growth of interest per second of simulated time (1/s).
        settle_observations: A ROI that matches no entry is only a candidate; it settles
            as an entry once this many observations (one per frame) agreed on its place
            within the consistency radius. 1 settles every ROI at once.
        jitter_quantile: The consistency radius is this quantile of the robot's own
            position jitter: the distances between an entry and the ROIs associated with
            it, measured as the map runs.
        jitter_prior: Consistency radius (m) until ``jitter_samples`` distances are
            measured.
        jitter_samples: Distances needed before the measured quantile replaces the prior.
        max_object_height: Highest a ROI's centre can be above the ground (m): no object
            of a world file is larger (docs/world-files.md, ``size`` <= 0.5 m). Higher, or
            below the ground by more than the consistency radius, a ROI is impossible and
            never enters the map.
        max_height_per_width: Objects rest on the ground and none is taller than this many
            times its narrowest horizontal extent (a prism: 0.87 size high, size / 2 deep;
            the other shapes 1), so a ROI whose centre is higher above the ground than this
            times its measured size (``Roi.size_m``, plus the consistency radius) floats:
            a false stereo match, not an object.
    """

    association_radius: float = 0.15
    moved_threshold: float = 0.12
    vanish_frames: int = 3
    interest_rate: float = field(default=0.1, metadata={"live": True})
    settle_observations: int = 2
    jitter_quantile: float = 0.9
    jitter_prior: float = 0.05
    jitter_samples: int = 20
    max_object_height: float = 0.5
    max_height_per_width: float = 2.0

    def __post_init__(self) -> None:
        _check_range("SpatialMapConfig", "association_radius", self.association_radius,
                     0.0, 100.0, low_open=True)
        _check_range("SpatialMapConfig", "moved_threshold", self.moved_threshold,
                     0.0, 100.0, low_open=True)
        if self.moved_threshold > self.association_radius:
            raise ConfigError(
                "SpatialMapConfig.moved_threshold must not exceed association_radius "
                f"({self.association_radius!r}), got {self.moved_threshold!r}")
        _check_count("SpatialMapConfig", "vanish_frames", self.vanish_frames, low=1)
        _check_range("SpatialMapConfig", "interest_rate", self.interest_rate,
                     0.0, 1e6, low_open=True)
        _check_count("SpatialMapConfig", "settle_observations", self.settle_observations, low=1)
        _check_range("SpatialMapConfig", "jitter_quantile", self.jitter_quantile, 0.0, 1.0)
        _check_range("SpatialMapConfig", "jitter_prior", self.jitter_prior,
                     0.0, self.association_radius, low_open=True)
        _check_count("SpatialMapConfig", "jitter_samples", self.jitter_samples, low=1)
        for name in ("max_object_height", "max_height_per_width"):
            _check_range("SpatialMapConfig", name, getattr(self, name), 0.0, 100.0,
                         low_open=True)


@dataclass(frozen=True)
class AttentionConfig:
    """Everything the AttentionController needs; the policy is one switch (issue item 7).

    Attributes:
        policy: "straightforward" (section 4.1) or "qlearning" (section 4.2).
        visual_trials: Visual improvements allowed per focus before the match is final.
        haptic_trials: Haptic improvements allowed per focus before the match is final.
        home_targets: Points (x, y, z triples, robot frame, m) fixated in turn by the
            initial scan that settles the map before the first cycle (and again whenever
            the map is empty).
        visibility_margin: A map place counts as in view (so that not seeing it there
            counts towards vanishing) when it projects at least this fraction of the
            retina's width inside the image edge.
        rewards: Reward magnitudes (section 4.2, circumstances a-c).
        qlearning: Q-learning parameters.
        spatial_map: Spatial-map parameters.
    """

    policy: str = "straightforward"
    visual_trials: int = 1
    haptic_trials: int = 1
    home_targets: tuple[float, ...] = HOME_TARGETS
    visibility_margin: float = 0.1
    rewards: RewardConfig = field(default_factory=RewardConfig)
    qlearning: QLearningConfig = field(default_factory=QLearningConfig)
    spatial_map: SpatialMapConfig = field(default_factory=SpatialMapConfig)

    def __post_init__(self) -> None:
        if self.policy not in POLICY_NAMES:
            raise ConfigError(
                f"AttentionConfig.policy must be one of {POLICY_NAMES}, got {self.policy!r}")
        _check_count("AttentionConfig", "visual_trials", self.visual_trials)
        _check_count("AttentionConfig", "haptic_trials", self.haptic_trials)
        targets = self.home_targets
        if (not isinstance(targets, tuple) or not targets or len(targets) % 3
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                           and math.isfinite(v) for v in targets)):
            raise ConfigError("AttentionConfig.home_targets must hold finite x, y, z "
                              f"triples, got {targets!r}")
        _check_range("AttentionConfig", "visibility_margin", self.visibility_margin, 0.0, 0.5)
        for name, kind in (("rewards", RewardConfig), ("qlearning", QLearningConfig),
                           ("spatial_map", SpatialMapConfig)):
            if not isinstance(getattr(self, name), kind):
                raise ConfigError(
                    f"AttentionConfig.{name} must be a {kind.__name__}, "
                    f"got {getattr(self, name)!r}")

    @property
    def scan_targets(self) -> tuple[tuple[float, float, float], ...]:
        """``home_targets`` as (x, y, z) points."""
        t = self.home_targets
        return tuple((float(t[i]), float(t[i + 1]), float(t[i + 2]))
                     for i in range(0, len(t), 3))


@dataclass(frozen=True)
class AttentionNodeConfig:
    """What the attention node needs besides the core's AttentionConfig.

    Attributes:
        seed: Seed of the policy's exploration.
        qtable_file: Q-table file: loaded at start if it exists, saved atomically after
            every cycle while learning. Empty: kept in RAM only.
        learn: Q-learning: update the table (training) or only run it.
        max_cycles: Stop after this many control cycles; 0 runs until shut down.
        stop_when_complete: Stop once no new object was stored for this many cycles and no
            entry of the spatial map is left unmapped (the robot's own completion rule);
            0 never stops so.
        wait_for_observers: Start only once this many subscriptions listen on
            /roger/policy_state (the orchestrator's monitor sets 1), so that no cycle goes
            unrecorded.
        retry_after_s: Wall seconds without an answer before a goal or request is re-sent.
    """

    seed: int = 0
    qtable_file: str = ""
    learn: bool = True
    max_cycles: int = field(default=0, metadata={"live": True})
    stop_when_complete: int = field(default=0, metadata={"live": True})
    wait_for_observers: int = field(default=0, metadata={"live": True})
    retry_after_s: float = field(default=10.0, metadata={"live": True})

    def __post_init__(self) -> None:
        _check_count("AttentionNodeConfig", "seed", self.seed)
        _check_count("AttentionNodeConfig", "max_cycles", self.max_cycles)
        _check_count("AttentionNodeConfig", "stop_when_complete", self.stop_when_complete)
        _check_count("AttentionNodeConfig", "wait_for_observers", self.wait_for_observers)
        _check_range("AttentionNodeConfig", "retry_after_s", self.retry_after_s, 0.0, 1e6,
                     low_open=True)
        if not isinstance(self.qtable_file, str) or not isinstance(self.learn, bool):
            raise ConfigError("AttentionNodeConfig: qtable_file must be a string and learn "
                              f"a bool, got {self.qtable_file!r}, {self.learn!r}")


@dataclass(frozen=True)
class FsmEnvConfig:
    """The abstract FSM-only environment used to train and test the Q-learning policy.

    Each ROI that attention lands on is drawn at random: already mapped with probability
    ``p_mapped`` (a mapped object is always in memory), otherwise known to memory with
    probability ``p_known``. A non-final match identifies a known object with the
    probability of the action that preceded it; an unknown object stays undetermined until
    the final trial, which answers IDENTIFIED for a known object and NEW otherwise.

    Attributes:
        p_mapped: Probability that a shift lands on an already mapped ROI.
        p_known: Probability that an un-mapped ROI's object is already in memory.
        p_identify_shift: Identification probability of the match after a shift.
        p_identify_visual: ... after a visual improvement.
        p_identify_haptic: ... after a haptic improvement (the paper notes it is the more
            effective one).
        visual_trials: As in AttentionConfig.
        haptic_trials: As in AttentionConfig.
        max_episode_steps: An episode not ended by a map update is truncated here.
        rewards: As in AttentionConfig.
    """

    p_mapped: float = 0.25
    p_known: float = 0.5
    p_identify_shift: float = 0.3
    p_identify_visual: float = 0.5
    p_identify_haptic: float = 0.7
    visual_trials: int = 1
    haptic_trials: int = 1
    max_episode_steps: int = 50
    rewards: RewardConfig = field(default_factory=RewardConfig)

    def __post_init__(self) -> None:
        for name in ("p_mapped", "p_known", "p_identify_shift", "p_identify_visual",
                     "p_identify_haptic"):
            _check_range("FsmEnvConfig", name, getattr(self, name), 0.0, 1.0)
        if self.p_mapped >= 1.0:
            raise ConfigError(f"FsmEnvConfig.p_mapped must be < 1, got {self.p_mapped!r}")
        _check_count("FsmEnvConfig", "visual_trials", self.visual_trials)
        _check_count("FsmEnvConfig", "haptic_trials", self.haptic_trials)
        _check_count("FsmEnvConfig", "max_episode_steps", self.max_episode_steps, low=1)
        if not isinstance(self.rewards, RewardConfig):
            raise ConfigError(f"FsmEnvConfig.rewards must be a RewardConfig, "
                              f"got {self.rewards!r}")
