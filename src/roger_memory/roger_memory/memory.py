"""The central associative memory of section 2: match a feature pattern, store a new one.

A match has three outcomes (section 4.2, cases a-c): IDENTIFIED (address, confidence), NEW
(only on the caller's final trial: all improvements used up and still nothing matches) and
UNDETERMINED (not sure yet: improve the features). The BP network's winner-take-all output
proposes an address; the proposal is checked against the stored exemplars on the features
known both in the query and in the exemplar:

* distance to an exemplar: root-mean-square difference over the common known features, and
  the exemplar *matches* when that RMS <= ``acceptance_distance`` and no single common
  feature differs by more than ``max_component_difference``;
* an address is a *candidate* when one of its exemplars matches; its distance is that of
  its nearest matching exemplar.

Non-final match: IDENTIFIED iff the network's winner is a candidate, its winner-take-all
confidence is >= ``confidence_threshold``, and no other candidate is within
``ambiguity_margin`` of its distance; otherwise UNDETERMINED (with the winner as best guess).
Final match: IDENTIFIED if there is any candidate (the winner if it is one, else the
nearest candidate), otherwise NEW. The memory is never changed by a match.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch

from roger_common.errors import ConfigError, MemoryFileError, MessageError
from roger_common.types import (
    FEATURE_DIM,
    MatchOutcome,
    MatchResult,
    MemoryOp,
    MemoryRequest,
)
from roger_memory.config import ARCHITECTURE_FIELDS, DEFAULT_CONFIG, MemoryConfig
from roger_memory.network import AssociativeNetwork, train_replay, warm_up_optimizer
from roger_memory.persistence import MemorySnapshot, load_snapshot, save_snapshot


class AssociativeMemory:
    """BP network with winner-take-all over a growing long-term memory of exemplars.

    Args:
        config: Network sizes, training budget and match thresholds.
        seed: Seed of every random draw (initial weights, replay batches); the same seed
            and the same sequence of stores give the same memory.
    """

    def __init__(self, config: MemoryConfig = DEFAULT_CONFIG, seed: int = 0) -> None:
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ConfigError(f"AssociativeMemory.seed={seed!r}: expected an int >= 0")
        self._config = config
        self._seed = int(seed)
        self._exemplars = np.zeros((0, FEATURE_DIM), np.float32, order="F")
        self._known = np.zeros((0, FEATURE_DIM), bool, order="F")
        self._addresses = np.zeros(0, np.int64)
        self._network = AssociativeNetwork(config.hidden_sizes, self._torch_generator(-1))
        self._network.eval()
        warm_up_optimizer()
        #: Replay steps the last store took (diagnostics and benchmarks).
        self.last_train_steps = 0

    @property
    def config(self) -> MemoryConfig:
        """The configuration in use."""
        return self._config

    @property
    def seed(self) -> int:
        """The seed of this memory."""
        return self._seed

    @property
    def size(self) -> int:
        """Number of long-term-memory addresses (stored objects)."""
        return self._network.n_addresses

    @property
    def network(self) -> AssociativeNetwork:
        """The BP network (read it, do not train it from outside)."""
        return self._network

    def exemplars(self, address: int) -> np.ndarray:
        """Copy of the exemplars of ``address``, shape (n, FEATURE_DIM); unknown entries 0."""
        self._check_address(address)
        return self._exemplars[self._addresses == address].copy()

    def exemplar_known(self, address: int) -> np.ndarray:
        """Copy of the known masks of the exemplars of ``address``, shape (n, FEATURE_DIM)."""
        self._check_address(address)
        return self._known[self._addresses == address].copy()

    def find_exact(self, features: np.ndarray, known: np.ndarray) -> int | None:
        """Lowest address holding an exemplar equal to this pattern, or None.

        Equal means the same known mask and the same value of every known feature: a
        STORE sent again after its reply was lost (the requester re-sends what it sent)
        is recognised, never a new look at an object.
        """
        x, k = _validate(features, known)
        same = np.all(self._known == k, axis=1) & np.all(
            np.where(k, self._exemplars == x, True), axis=1)
        hits = self._addresses[same]
        return int(hits.min()) if hits.size else None

    def distances(self, features: np.ndarray, known: np.ndarray) -> np.ndarray:
        """Distance of a pattern to every address (inf where no exemplar matches).

        The distance to an address is the smallest RMS difference, over the features known
        in both, among its exemplars that match (see the module docstring).

        Returns:
            (size,) float64.
        """
        x, k = _validate(features, known)
        return self._address_distances(x, k)

    def match(
        self, features: np.ndarray, known: np.ndarray, final_trial: bool = False
    ) -> MatchResult:
        """Match a feature pattern against the long-term memory (section 4.2).

        Args:
            features: FEATURE_DIM floats in [0, 1] (clipped); unknown entries are ignored.
            known: FEATURE_DIM booleans; False where a feature is not measured yet.
            final_trial: All improvement trials are used up: answer IDENTIFIED or NEW,
                never UNDETERMINED.

        Returns:
            IDENTIFIED (address, confidence), NEW (-1, 0.0; only when ``final_trial``) or
            UNDETERMINED (the network's winner as a best guess, or -1, and its confidence).

        Raises:
            MessageError: Wrong shape, or a known feature is not finite.
        """
        x, k = _validate(features, known)
        if self.size == 0:
            if final_trial:
                return MatchResult(MatchOutcome.NEW, -1, 0.0)
            return MatchResult(MatchOutcome.UNDETERMINED, -1, 0.0)
        winner, confidence, shares = self._network.recall(x, k)
        rms = self._exemplar_distances(x, k)
        mine = self._addresses == winner
        d_winner = rms[mine].min()
        d_other = rms[~mine].min(initial=np.inf)
        if final_trial:
            if np.isfinite(d_winner):
                return MatchResult(MatchOutcome.IDENTIFIED, winner, confidence)
            if not np.isfinite(d_other):
                return MatchResult(MatchOutcome.NEW, -1, 0.0)
            address = int(self._addresses[np.argmin(rms)])
            return MatchResult(MatchOutcome.IDENTIFIED, address, float(shares[address]))
        if (np.isfinite(d_winner) and confidence >= self._config.confidence_threshold
                and d_other > d_winner + self._config.ambiguity_margin):
            return MatchResult(MatchOutcome.IDENTIFIED, winner, confidence)
        return MatchResult(MatchOutcome.UNDETERMINED, winner, confidence)

    def store(self, features: np.ndarray, known: np.ndarray) -> int:
        """Supervised learning (step 4 of section 4.1): store a new object and retrain.

        Adds one exemplar and one network output unit, then retrains by replay of every
        stored exemplar (see :func:`roger_memory.network.train_replay`).

        Args:
            features: FEATURE_DIM floats in [0, 1]; known: which of them are measured.

        Returns:
            The new address: 0 for the first object, then 1, 2, ...

        Raises:
            MessageError: Wrong shape, a known feature not finite, or nothing known.
        """
        x, k = _validate(features, known, need_known=True)
        return self.store_many(x[None], k[None])[0]

    def store_many(self, features: np.ndarray, known: np.ndarray) -> list[int]:
        """Store several new objects with one retraining (e.g. to preload a memory).

        Args:
            features: (n, FEATURE_DIM) floats; known: (n, FEATURE_DIM) booleans.

        Returns:
            The n new addresses, in order.
        """
        rows = [_validate(f, k, need_known=True) for f, k in zip(features, known, strict=True)]
        if not rows:
            return []
        new: list[int] = []
        for x, k in rows:
            address = self._network.add_address(self._torch_generator(self.size))
            self._append(address, x, k)
            new.append(address)
        self._retrain(focus=new[0] if len(new) == 1 else -1)
        return new

    def add_exemplar(self, address: int, features: np.ndarray, known: np.ndarray) -> bool:
        """Refine an address with one more exemplar (e.g. its weight, measured later).

        Never called by :meth:`match`: identifications do not change the memory.

        Returns:
            True if added (and the network retrained); False when the address already holds
            ``max_exemplars_per_address`` exemplars.
        """
        self._check_address(address)
        x, k = _validate(features, known, need_known=True)
        if np.count_nonzero(self._addresses == address) >= self._config.max_exemplars_per_address:
            return False
        self._append(address, x, k)
        self._retrain(focus=address)
        return True

    def handle(self, req: MemoryRequest) -> MatchResult:
        """Answer a request: MATCH -> :meth:`match`; STORE -> MatchResult(NEW, address, 1.0)."""
        if req.op == MemoryOp.STORE:
            return MatchResult(MatchOutcome.NEW, self.store(req.features, req.known), 1.0)
        if req.op == MemoryOp.MATCH:
            return self.match(req.features, req.known, req.final_trial)
        raise MessageError(f"MemoryRequest {req.request_id}: unknown op {req.op!r}")

    def snapshot(self) -> MemorySnapshot:
        """Copy of everything that :meth:`save` writes."""
        weights = {k: v.detach().numpy().copy() for k, v in self._network.state_dict().items()}
        return MemorySnapshot(self._config.to_dict(), self._seed, self.size,
                              self._exemplars.copy(), self._known.copy(),
                              self._addresses.copy(), weights)

    @classmethod
    def from_snapshot(
        cls, snap: MemorySnapshot, config: MemoryConfig | None = None, source: str = "<snapshot>"
    ) -> AssociativeMemory:
        """Rebuild a memory from a snapshot (see :meth:`load`; ``source`` names it in errors).

        Raises:
            MemoryFileError: The snapshot does not fit this code or ``config``.
        """
        try:
            saved = MemoryConfig.from_dict(snap.config)
        except (ConfigError, TypeError) as exc:
            raise MemoryFileError(f"{source}: incompatible configuration ({exc})") from exc
        config = saved if config is None else config
        for name in ARCHITECTURE_FIELDS:
            if getattr(config, name) != getattr(saved, name):
                raise MemoryFileError(
                    f"{source}: {name}={getattr(saved, name)} in the file but "
                    f"{getattr(config, name)} in the configuration; use the file's value "
                    "or start a new memory file")
        memory = cls(config, snap.seed)
        for address in range(snap.n_addresses):
            memory._network.add_address(memory._torch_generator(address))
        try:
            state = {k: torch.from_numpy(np.ascontiguousarray(v)) for k, v in snap.weights.items()}
            memory._network.load_state_dict(state, strict=True)
        except (RuntimeError, TypeError) as exc:
            raise MemoryFileError(f"{source}: network weights do not fit ({exc})") from exc
        memory._network.eval()
        memory._exemplars = np.asfortranarray(snap.exemplars, np.float32).copy(order="F")
        memory._known = np.asfortranarray(snap.known, bool).copy(order="F")
        memory._addresses = np.asarray(snap.addresses, np.int64).copy()
        return memory

    def save(self, path: str | os.PathLike[str], durable: bool = True) -> None:
        """Write the long-term memory to ``path`` atomically (old or new file, never broken).

        ``durable``: fsync too (see :func:`roger_common.atomic.atomic_write_bytes`).
        """
        save_snapshot(self.snapshot(), path, durable=durable)

    @classmethod
    def load(
        cls, path: str | os.PathLike[str], config: MemoryConfig | None = None
    ) -> AssociativeMemory:
        """Read a long-term memory written by :meth:`save`.

        Args:
            path: The memory file.
            config: Configuration to use (thresholds may differ from the file's, the network
                sizes may not); None uses the one stored in the file.

        Raises:
            MemoryFileError: Missing, cut off, corrupt or incompatible file (names it).
        """
        return cls.from_snapshot(load_snapshot(path), config, str(path))

    @classmethod
    def open(
        cls, path: str | os.PathLike[str], config: MemoryConfig | None = None, seed: int = 0
    ) -> AssociativeMemory:
        """Load ``path`` if it exists, else start an empty memory (the first run).

        Raises:
            MemoryFileError: The file exists but cannot be used.
        """
        if Path(path).exists():
            return cls.load(path, config)
        return cls(config or DEFAULT_CONFIG, seed)

    # -- internals -------------------------------------------------------------------

    def _exemplar_distances(self, x: np.ndarray, k: np.ndarray) -> np.ndarray:
        """RMS difference to every exemplar over the common known features; inf if no match."""
        # The exemplar arrays are Fortran-ordered: these row reductions then run down
        # contiguous columns, several times faster at 1,000 exemplars.
        common = self._known & k
        n_common = common.sum(axis=1)
        diff = (self._exemplars - x) * common
        sq = (diff * diff).sum(axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            rms = np.sqrt(sq / n_common)
        ok = ((n_common > 0) & (rms <= self._config.acceptance_distance)
              & (np.abs(diff).max(axis=1) <= self._config.max_component_difference))
        return np.where(ok, rms, np.inf)

    def _address_distances(self, x: np.ndarray, k: np.ndarray) -> np.ndarray:
        dist = np.full(self.size, np.inf)
        np.minimum.at(dist, self._addresses, self._exemplar_distances(x, k))
        return dist

    def _append(self, address: int, x: np.ndarray, k: np.ndarray) -> None:
        self._exemplars = np.asfortranarray(
            np.vstack([self._exemplars, np.where(k, x, 0.0)[None]]), np.float32)
        self._known = np.asfortranarray(np.vstack([self._known, k[None]]))
        self._addresses = np.append(self._addresses, np.int64(address))

    def _retrain(self, focus: int) -> None:
        rng = np.random.default_rng([self._seed, len(self._addresses), self.size])
        self.last_train_steps = train_replay(
            self._network, self._exemplars, self._known, self._addresses, focus,
            self._config, rng)

    def _torch_generator(self, address: int) -> torch.Generator:
        # One generator per output unit, derived from (seed, address): no RNG state needs
        # saving, and a loaded memory rebuilds exactly the same layers.
        state = np.random.SeedSequence([self._seed, address + 1]).generate_state(1, np.uint64)
        return torch.Generator().manual_seed(int(state[0]))

    def _check_address(self, address: int) -> None:
        if not 0 <= address < self.size:
            raise IndexError(f"address {address} outside [0, {self.size})")


def _validate(
    features: np.ndarray, known: np.ndarray, need_known: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Checked copies: float32 features clipped to [0, 1] (0 where unknown), bool mask."""
    x = np.asarray(features, np.float64).reshape(-1)
    k = np.asarray(known).reshape(-1)
    if x.shape != (FEATURE_DIM,) or k.shape != (FEATURE_DIM,):
        raise MessageError(
            f"features/known must have {FEATURE_DIM} entries, got {x.size} and {k.size}")
    k = k.astype(bool)
    if not np.all(np.isfinite(x[k])):
        raise MessageError("a known feature is NaN or infinite")
    if need_known and not k.any():
        raise MessageError("cannot store a pattern with no known feature")
    return np.where(k, np.clip(np.nan_to_num(x), 0.0, 1.0), 0.0).astype(np.float32), k
