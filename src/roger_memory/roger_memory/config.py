"""Parameters of the associative memory: network sizes, replay training and match thresholds.

Every default is explained in docs/memory.md. Values flow one way: ROS parameters ->
MemoryConfig -> AssociativeMemory.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields
from typing import Any, NoReturn

from roger_common.errors import ConfigError
from roger_common.types import FEATURE_NAMES

#: Fields that fix the shape of the network; a memory file is only compatible with a
#: configuration that agrees on them.
ARCHITECTURE_FIELDS: tuple[str, ...] = ("hidden_sizes",)


@dataclass(frozen=True)
class MemoryConfig:
    """Configuration of :class:`roger_memory.memory.AssociativeMemory`.

    Attributes:
        hidden_sizes: Units of each hidden layer of the BP network (tanh).
        learning_rate: Adam step size of the supervised learning module.
        batch_size: Samples per replay step.
        train_steps: Replay steps always taken after a store (a fixed budget, so that a
            store costs about the same at 10 and at 1,000 objects).
        check_every: After ``train_steps``, training goes on in blocks of this many steps
            until every stored exemplar is recalled (see ``recall_confidence``).
        max_train_steps: Cap on the replay steps of one store.
        recall_confidence: An exemplar counts as recalled (ending training) when, with its
            own known mask, its address wins with at least this softmax share.
        new_fraction: Share of each replay batch drawn from the address being learned;
            the rest replays every stored exemplar uniformly.
        train_noise_std: Std of the Gaussian noise added to replayed exemplars, so the
            network tolerates the noise of real features.
        unknown_feature_prob: Probability that a replayed sample has each feature named
            in ``maskable_features`` turned unknown, so that the network also answers
            before a haptic improvement.
        maskable_features: Features that may be unknown at match time (FEATURE_NAMES).
        acceptance_distance: Largest root-mean-square difference, over the features known
            both in the query and in an exemplar, for the exemplar to match.
        max_component_difference: Largest difference of any single known feature for an
            exemplar to match (catches objects that differ in one feature only).
        ambiguity_margin: A non-final match is undetermined when another address matches
            within this much RMS distance of the best one.
        confidence_threshold: Smallest winner-take-all confidence (softmax share of the
            winner) for a non-final identification.
        max_exemplars_per_address: Exemplars kept per address by ``add_exemplar``.
    """

    hidden_sizes: tuple[int, ...] = field(default=(64,), metadata={
        "doc": "Units of each tanh hidden layer of the BP network"})
    learning_rate: float = field(default=0.01, metadata={
        "doc": "Adam step size of the supervised learning module"})
    batch_size: int = field(default=128, metadata={
        "doc": "Exemplars per replay step"})
    train_steps: int = field(default=50, metadata={
        "doc": "Replay steps always taken after a store"})
    check_every: int = field(default=25, metadata={
        "doc": "Then more steps in blocks of this many until every exemplar is recalled"})
    max_train_steps: int = field(default=1000, metadata={
        "doc": "Cap on the replay steps of one store"})
    recall_confidence: float = field(default=0.75, metadata={
        "doc": "Winner share each stored exemplar must reach to end training"})
    new_fraction: float = field(default=0.1, metadata={
        "doc": "Share of each replay batch drawn from the object just stored"})
    train_noise_std: float = field(default=0.02, metadata={
        "doc": "Std of the noise added to replayed exemplars"})
    unknown_feature_prob: float = field(default=0.5, metadata={
        "doc": "Probability that a replayed maskable feature is made unknown"})
    maskable_features: tuple[str, ...] = field(default=("W",), metadata={
        "doc": "Features that may be unknown at match time (FEATURE_NAMES)"})
    acceptance_distance: float = field(default=0.04, metadata={
        "doc": "Largest RMS difference over common known features for a match"})
    max_component_difference: float = field(default=0.12, metadata={
        "doc": "Largest difference of any one known feature for a match"})
    ambiguity_margin: float = field(default=0.02, metadata={
        "doc": "Undetermined when another address matches within this RMS distance"})
    confidence_threshold: float = field(default=0.5, metadata={
        "doc": "Smallest winner-take-all share for a non-final identification"})
    max_exemplars_per_address: int = field(default=8, metadata={
        "doc": "Exemplars kept per address by add_exemplar"})

    def __post_init__(self) -> None:
        hidden = tuple(self.hidden_sizes)
        if not hidden or any(not isinstance(h, int) or h < 1 for h in hidden):
            _fail("hidden_sizes", self.hidden_sizes, "a non-empty tuple of positive ints")
        object.__setattr__(self, "hidden_sizes", hidden)
        object.__setattr__(self, "maskable_features", tuple(self.maskable_features))
        for name in self.maskable_features:
            if name not in FEATURE_NAMES:
                _fail("maskable_features", self.maskable_features, f"names in {FEATURE_NAMES}")
        _positive("learning_rate", self.learning_rate)
        _positive_int("batch_size", self.batch_size)
        _positive_int("train_steps", self.train_steps)
        _positive_int("check_every", self.check_every)
        _positive_int("max_train_steps", self.max_train_steps)
        if self.max_train_steps < self.train_steps:
            _fail("max_train_steps", self.max_train_steps, f">= train_steps={self.train_steps}")
        _unit("recall_confidence", self.recall_confidence)
        _unit("new_fraction", self.new_fraction)
        _unit("unknown_feature_prob", self.unknown_feature_prob)
        _non_negative("train_noise_std", self.train_noise_std)
        _positive("acceptance_distance", self.acceptance_distance)
        _positive("max_component_difference", self.max_component_difference)
        _non_negative("ambiguity_margin", self.ambiguity_margin)
        _unit("confidence_threshold", self.confidence_threshold)
        _positive_int("max_exemplars_per_address", self.max_exemplars_per_address)

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-friendly dict of every field (tuples become lists)."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> MemoryConfig:
        """Inverse of :meth:`to_dict`; unknown keys raise ConfigError.

        Raises:
            ConfigError: A key is not a field or a value is out of range.
        """
        names = {f.name for f in fields(cls)}
        extra = sorted(set(data) - names)
        if extra:
            raise ConfigError(f"MemoryConfig: unknown field(s) {extra}")
        kwargs: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v
                                  for k, v in data.items()}
        return cls(**kwargs)


def _fail(name: str, value: object, expected: str) -> NoReturn:
    raise ConfigError(f"MemoryConfig.{name}={value!r}: expected {expected}")


def _finite(name: str, value: float) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        _fail(name, value, "a finite number")


def _positive(name: str, value: float) -> None:
    _finite(name, value)
    if value <= 0:
        _fail(name, value, "> 0")


def _non_negative(name: str, value: float) -> None:
    _finite(name, value)
    if value < 0:
        _fail(name, value, ">= 0")


def _unit(name: str, value: float) -> None:
    _finite(name, value)
    if not 0.0 <= value <= 1.0:
        _fail(name, value, "in [0, 1]")


def _positive_int(name: str, value: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        _fail(name, value, "a positive int")


#: The defaults, shared (the dataclass is frozen).
DEFAULT_CONFIG = MemoryConfig()


@dataclass(frozen=True)
class MemoryNodeConfig:
    """What the memory node needs besides MemoryConfig.

    Attributes:
        memory_file: Long-term memory file; loaded at start if it exists, written
            atomically after each store. Empty: memory lives in RAM only.
        seed: Seed of the network's initial weights and training order.
    """

    memory_file: str = ""
    seed: int = 0

    def __post_init__(self) -> None:
        if not isinstance(self.memory_file, str):
            raise ConfigError(f"MemoryNodeConfig.memory_file must be a file name, got "
                              f"{self.memory_file!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ConfigError(f"MemoryNodeConfig.seed must be an integer >= 0, got {self.seed!r}")
