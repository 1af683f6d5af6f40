"""The central associative memory of section 2: match a feature pattern, store a new one.

A match has three outcomes (section 4.2, cases a-c): IDENTIFIED (address, confidence), NEW
(only on the caller's final trial: all improvements used up and still nothing matches) and
UNDETERMINED (not sure yet: improve the features). The BP network decides
(:mod:`roger_memory.network`): its winner-take-all over one output per address and one
*novel* output gives the address, and the winner's softmax share gives the confidence.

* Final match: the winning address is IDENTIFIED; the novel unit winning is NEW. A look
  that knows fewer than ``min_common_features`` features (only the weight of an object
  hidden behind another) is UNDETERMINED even then: no unit can compare it, and an
  address stored from it could never be matched.
* Non-final match: IDENTIFIED iff an address wins with a share >= ``identify_share`` and
  the query knows every feature the address knows (vision alone cannot exclude a stored
  object that differs in the weight, so a look without W is never identified as an
  address that has W); otherwise UNDETERMINED, with the winning address as best guess.
* A distance veto remains: one of the winner's stored looks, one that compares every
  feature the address can compare with the query, must not differ from it in any feature
  by more than ``veto`` (a difference never seen between two looks of one object;
  ``MemoryConfig.veto_any_look``). After a veto the vetoed unit is inhibited
  and the winner-take-all runs once more over the units left (``veto_rerun``): the next
  address wins if the veto lets it pass. Otherwise the veto turns IDENTIFIED into
  UNDETERMINED (non-final) or NEW (final). Each veto is counted in
  :attr:`AssociativeMemory.stats`. Between two looks the hand found smooth and
  flat-topped (``MemoryConfig.flat_veto``: a box's or cylinder's top) the fovea's outline
  O and the brightest grey A veto too, and between two whose outlines are both
  straight-edged (``straight_veto``: a box's top) A vetoes closer; elsewhere they vary
  with the view and do not. A query whose touches found a crease, and no flat top's rim,
  is turned down by an address none of whose looks found one (``crease_found_veto``;
  one-sided: none found is no evidence of none); its mirror, a query whose pad lay flat
  over a top's rim and found no crease, by an address all of whose touched looks found a
  crease and no rim (``rim_found_veto``).

Each address holds several looks: the looks of the focus that stored it (the requests
carry the focus id) and, later, looks of foci identified as it, added only when one of
the address's *stored* looks accepts them, so an address never grows by more than one
acceptance radius from what was stored (no chaining, docs/memory.md).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from roger_common.configdoc import check_live_change
from roger_common.errors import ConfigError, MemoryFileError, MessageError
from roger_common.types import (
    WEIGHT_INDEX,
    MatchOutcome,
    MatchResult,
    MemoryOp,
    MemoryRequest,
    feature_dim,
    feature_names,
)
from roger_memory.calibration import (
    creased_looks,
    curved_looks,
    flat_looks,
    rms_z,
    uncreased_common,
)
from roger_memory.config import ARCHITECTURE_FIELDS, DEFAULT_CONFIG, MemoryConfig
from roger_memory.network import AssociativeNetwork, train_replay, warm_up_optimizer
from roger_memory.persistence import MemorySnapshot, load_snapshot, save_snapshot


@dataclass
class MemoryStats:
    """What the memory decided since it was built (not saved with it).

    Attributes:
        matches: Match requests answered (memory not empty).
        identified: IDENTIFIED answers.
        new: NEW answers.
        undetermined: UNDETERMINED answers.
        vetoes: Identifications by the network that the distance veto turned down.
        coverage_holds: Non-final identifications held back because the address knows a
            feature (the weight) that the query does not.
        refinements: Looks added to an address after an identification.
        unseen: Final trials answered UNDETERMINED because the look knows fewer than
            ``min_common_features`` features (e.g. only W of an object hidden behind
            another): nothing to compare, and nothing a store could match again.
    """

    matches: int = 0
    identified: int = 0
    new: int = 0
    undetermined: int = 0
    vetoes: int = 0
    coverage_holds: int = 0
    refinements: int = 0
    unseen: int = 0


@dataclass(frozen=True)
class Decision:
    """A match with everything the network said (for tests, notes and ablations).

    Attributes:
        result: The answer.
        winner: The network's winning output: -1 for the novel unit, else an address.
        share: The winner's softmax share.
        distance: RMS z-distance of the query to the winner's nearest look (inf if none).
        vetoed: The distance veto turned the network's identification down.
        held: The non-final identification was held back (coverage or share).
    """

    result: MatchResult
    winner: int
    share: float
    distance: float
    vetoed: bool
    held: bool


class AssociativeMemory:
    """BP network with winner-take-all over a growing long-term memory of looks.

    Args:
        config: Calibration, decision thresholds and training budget.
        seed: Seed of every random draw (replay batches and noise); the same seed and the
            same sequence of requests give the same memory.
    """

    def __init__(self, config: MemoryConfig = DEFAULT_CONFIG, seed: int = 0) -> None:
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ConfigError(f"AssociativeMemory.seed={seed!r}: expected an int >= 0")
        self._config = config
        self._seed = int(seed)
        self._dim = feature_dim(config.features)
        self._exemplars = np.zeros((0, self._dim), np.float32)
        self._known = np.zeros((0, self._dim), bool)
        self._addresses = np.zeros(0, np.int64)
        self._stored = np.zeros(0, bool)
        self._network = AssociativeNetwork(config.feature_scale, config.identify_distance,
                                           config.min_common_features, config.feature_weight,
                                           config.z_cap)
        self._network.eval()
        self._focus_id = 0
        self._focus_looks: list[tuple[np.ndarray, np.ndarray]] = []
        self._set_vetoes(config)
        warm_up_optimizer()
        #: Replay steps the last training took (diagnostics and benchmarks).
        self.last_train_steps = 0
        #: Counts of the decisions since the memory was built.
        self.stats = MemoryStats()
        #: Grows with every change of the long-term memory (a store, a refinement).
        self.revision = 0

    @property
    def config(self) -> MemoryConfig:
        """The configuration in use."""
        return self._config

    def reconfigure(self, config: MemoryConfig) -> None:
        """Take a new configuration that differs only in fields marked live (the vetoes,
        the flat-top veto's thresholds and ``identify_share``, read per request); the next
        decision uses it.

        Raises:
            ValueError: Another field differs (it shaped the network: restart to change).
        """
        check_live_change(self._config, config)
        self._config = config
        self._set_vetoes(config)

    def _set_vetoes(self, config: MemoryConfig) -> None:
        self._veto = np.asarray(config.veto, np.float32)
        self._flat_veto = np.minimum(self._veto, np.asarray(config.flat_veto, np.float32))
        self._straight_veto = np.minimum(self._flat_veto,
                                         np.asarray(config.straight_veto, np.float32))
        self._curved_veto = np.minimum(self._veto, np.asarray(config.curved_veto, np.float32))
        names = feature_names(config.features)
        # The flat-top and curved vetoes need the touch's crease and curvature (extended
        # mode).
        self._flat_columns = ((names.index("TC"), names.index("TK"))
                              if "TC" in names and "TK" in names
                              and (np.any(self._straight_veto < self._veto)
                                   or np.any(self._curved_veto < self._veto)) else None)
        # The straight-edged tops' veto needs the outline (extended mode).
        self._outline_column = (names.index("O") if "O" in names
                                and np.any(self._straight_veto < self._flat_veto) else None)
        # Between two creased looks the features of creased_unused count not.
        unused = np.array([n in config.creased_unused for n in names])
        self._crease_gate = ((names.index("TC"), config.flat_crease, unused)
                             if "TC" in names and unused.any() else None)
        self._network.set_crease_gate(*(self._crease_gate or (None, 0.0, None)))
        # A crease found is not an address that never found one (crease_found_veto).
        self._crease_found = ((names.index("TC"), names.index("TR")) if "TR" in names
                              and config.crease_found_veto else None)
        # A flat top's rim felt is not an address that only ever found a crease
        # (rim_found_veto).
        self._rim_found = ((names.index("TC"), names.index("TR")) if "TR" in names
                           and config.rim_found_veto else None)

    def veto_between(self, features: np.ndarray, known: np.ndarray,
                     other: np.ndarray, other_known: np.ndarray) -> np.ndarray:
        """The per-feature veto between two looks: ``veto``; the smaller ``flat_veto``
        where the hand found both smooth and flat-topped; the smaller still
        ``straight_veto`` where both flat tops' outlines are straight-edged too; the
        smaller ``curved_veto`` where the hand found both smooth and curved."""
        features, known = np.asarray(features), np.asarray(known, bool)
        other, other_known = np.asarray(other), np.asarray(other_known, bool)
        if self._flat_columns is None:
            return self._veto
        if self._curved(features, known) and self._curved(other, other_known):
            return self._curved_veto
        if not self._flat(features, known) or not self._flat(other, other_known):
            return self._veto
        o = self._outline_column
        if (o is not None and known[o] and other_known[o]
                and min(features[o], other[o]) >= self._config.straight_outline):
            return self._straight_veto
        return self._flat_veto

    def _flat(self, features: np.ndarray, known: np.ndarray) -> bool:
        assert self._flat_columns is not None
        crease, curvature = self._flat_columns
        return bool(flat_looks(features[None, :], known[None, :], crease, curvature,
                               self._config.flat_crease, self._config.flat_curvature)[0])

    def _curved(self, features: np.ndarray, known: np.ndarray) -> bool:
        assert self._flat_columns is not None
        crease, curvature = self._flat_columns
        return bool(curved_looks(features[None, :], known[None, :], crease, curvature,
                                 self._config.flat_crease, self._config.flat_curvature)[0])

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
        """Copy of the looks of ``address``, shape (n, F); unknown entries 0."""
        self._check_address(address)
        return self._exemplars[self._addresses == address].copy()

    def exemplar_known(self, address: int) -> np.ndarray:
        """Copy of the known masks of the looks of ``address``, shape (n, F)."""
        self._check_address(address)
        return self._known[self._addresses == address].copy()

    def find_exact(self, features: np.ndarray, known: np.ndarray) -> int | None:
        """Lowest address holding a look equal to this pattern, or None.

        Equal means the same known mask and the same value of every known feature: a
        STORE sent again after its reply was lost (the requester re-sends what it sent)
        is recognised, never a new look at an object.
        """
        x, k = _validate(features, known, self._dim, self._config.features)
        same = np.all(self._known == k, axis=1) & np.all(
            np.where(k, self._exemplars == x, True), axis=1)
        hits = self._addresses[same]
        return int(hits.min()) if hits.size else None

    def distances(self, features: np.ndarray, known: np.ndarray) -> np.ndarray:
        """Weighted RMS z-distance (calibrated scales and weights) of a pattern to each
        address's nearest look, whatever the never-weighed rule (docs/memory.md).

        inf where no look shares ``min_common_features`` known features with it.

        Returns:
            (size,) float64.
        """
        x, k = _validate(features, known, self._dim, self._config.features)
        d = _rms_z(self._exemplars, self._known, x, k, np.asarray(self._config.feature_scale),
                   self._config.min_common_features, self._config.feature_weight,
                   self._config.z_cap, self._crease_gate)
        out = np.full(self.size, np.inf)
        np.minimum.at(out, self._addresses, d)
        return out

    def match(self, features: np.ndarray, known: np.ndarray, final_trial: bool = False,
              focus_id: int = 0) -> MatchResult:
        """Match a feature pattern against the long-term memory (section 4.2).

        Args:
            features: F floats in [0, 1] (clipped); unknown entries are ignored.
            known: F booleans; False where a feature is not measured yet.
            final_trial: All improvement trials are used up: answer IDENTIFIED or NEW;
                UNDETERMINED only when the look knows fewer than ``min_common_features``
                features (nothing to compare, nothing to learn).
            focus_id: The focus the look belongs to (0: none). The looks of one focus
                are kept until the next focus: a STORE stores them all, an identification
                may refine its address with them.

        Returns:
            IDENTIFIED (address, confidence), NEW (-1, 0.0; only when ``final_trial``) or
            UNDETERMINED (the network's winning address as a best guess, or -1, and its
            share).

        Raises:
            MessageError: Wrong shape, or a known feature is not finite.
        """
        return self.decide(features, known, final_trial, focus_id).result

    def decide(self, features: np.ndarray, known: np.ndarray, final_trial: bool = False,
               focus_id: int = 0, network: AssociativeNetwork | None = None) -> Decision:
        """:meth:`match` with the network's whole answer.

        ``network`` replaces the memory's own network for this one decision (ablations);
        nothing is then remembered of the look.
        """
        x, k = _validate(features, known, self._dim, self._config.features)
        if network is None:
            self._keep_look(focus_id, x, k)
        net = network or self._network
        if final_trial and int(k.sum()) < self._config.min_common_features:
            # Too little seen to compare with anything (no unit answers a look that knows
            # fewer than min_common_features features), and an address stored from it
            # could never be matched again: nothing to decide on, nothing to learn.
            self.stats.matches += int(self.size > 0)
            self.stats.unseen += 1
            self._count(MatchOutcome.UNDETERMINED)
            return Decision(MatchResult(MatchOutcome.UNDETERMINED, -1, 0.0), -1, 0.0, np.inf,
                            False, False)
        if self.size == 0:
            outcome = MatchOutcome.NEW if final_trial else MatchOutcome.UNDETERMINED
            self._count(outcome)
            return Decision(MatchResult(outcome, -1, 0.0), -1, 0.0, np.inf, False, False)
        self.stats.matches += 1
        output, share, shares, d2 = net.recall(x, k)
        winner = output - 1
        if winner < 0:
            guess = int(np.argmax(shares[1:]))
            distance = float(np.sqrt(d2.min()))
            result = (MatchResult(MatchOutcome.NEW, -1, 0.0) if final_trial else
                      MatchResult(MatchOutcome.UNDETERMINED, guess, float(shares[1 + guess])))
            self._count(result.outcome)
            return Decision(result, -1, share, distance, False, False)
        vetoed, distance = self._vetoed(winner, x, k, d2)
        if vetoed:
            self.stats.vetoes += 1
            if self._config.veto_rerun:
                rerun = self._rerun(winner, shares, x, k, d2)
                if rerun is not None:
                    winner, share, distance = rerun
                    vetoed = False
        mine = np.flatnonzero(self._addresses == winner)
        held = False
        if final_trial:
            result = (MatchResult(MatchOutcome.NEW, -1, 0.0) if vetoed else
                      MatchResult(MatchOutcome.IDENTIFIED, winner, share))
        else:
            # Touch can still tell: a look whose weight is not measured yet is not
            # identified before a haptic improvement (also not as an object never weighed).
            covered = bool(k[WEIGHT_INDEX]) and not np.any(self._known[mine].any(axis=0) & ~k)
            if not covered and not vetoed and share >= self._config.identify_share:
                self.stats.coverage_holds += 1
            held = not covered or share < self._config.identify_share
            if vetoed or held:
                result = MatchResult(MatchOutcome.UNDETERMINED, winner, share)
            else:
                result = MatchResult(MatchOutcome.IDENTIFIED, winner, share)
        self._count(result.outcome)
        if result.outcome is MatchOutcome.IDENTIFIED and network is None:
            self._refine(winner, x, k)
        return Decision(result, winner, share, distance, vetoed, held)

    def _vetoed(self, address: int, x: np.ndarray, k: np.ndarray, d2: np.ndarray
                ) -> tuple[bool, float]:
        """Whether the veto turns ``address`` down, and the RMS z-distance to its nearest
        look. With ``veto_any_look`` the address passes when one of its looks that can
        answer the query (``d2`` finite) and compares every feature some stored look of
        the address compares with the query is within the veto in every common feature; else
        its nearest look decides. With ``crease_found_veto`` a query that found a crease
        and felt no flat top's rim (TR unknown) is turned down by an address none of
        whose looks that measured TC found one; with ``rim_found_veto`` a query that felt
        a flat top's rim (TR known) and found no crease is turned down by an address
        every one of whose looks that measured TC found a crease and felt no rim."""
        mine = np.flatnonzero(self._addresses == address)
        nearest = mine[np.argmin(d2[mine])]
        if self._crease_found is not None:
            (tc, tr), full = self._crease_found, self._config.flat_crease
            felt = mine[self._known[mine, tc]]
            # A flat top's rim is a crease too: only a query that felt no flat top.
            if (k[tc] and x[tc] >= full and not k[tr] and len(felt)
                    and np.all(self._exemplars[felt, tc] < full)):
                return True, float(np.sqrt(d2[nearest]))
        if self._rim_found is not None:
            (tc, tr), full = self._rim_found, self._config.flat_crease
            felt = mine[self._known[mine, tc]]
            # The mirror: a pad that lay flat over a rim, no crease, is no prism's top.
            if (k[tr] and k[tc] and x[tc] < full and len(felt)
                    and np.all(self._exemplars[felt, tc] >= full)
                    and not np.any(self._known[felt, tr])):
                return True, float(np.sqrt(d2[nearest]))
        looks = [nearest]
        if self._config.veto_any_look:
            # Only a look that compares every feature some stored look of the address
            # compares may let it pass: one that never measured the feature that vetoes
            # cannot. A feature only refined looks know is no such feature: a refinement is
            # accepted on the features its stored looks know, so that one is unvouched.
            stored = mine[self._stored[mine]]
            comparable = self._known[stored if len(stored) else mine].any(axis=0) & k
            full = np.all(self._known[mine] | ~comparable, axis=1)
            looks = mine[np.isfinite(d2[mine]) & full]
        vetoed = True
        for i in (looks if len(looks) else [nearest]):
            common = self._known[i] & k
            veto = self.veto_between(x, k, self._exemplars[i], self._known[i])
            if not np.any(np.abs(self._exemplars[i] - x)[common] > veto[common]):
                vetoed = False
                break
        return vetoed, float(np.sqrt(d2[nearest]))

    def _rerun(self, vetoed_address: int, shares: np.ndarray, x: np.ndarray, k: np.ndarray,
               d2: np.ndarray) -> tuple[int, float, float] | None:
        """Inhibit the vetoed winner and let the WTA run again, once, over the units left.

        The novel unit winning, or the veto turning the next address down too, leaves the
        look as new as the veto said (None). An address the veto lets pass wins with its
        share renormalised over the units left: (address, share, distance). Once, not
        until something passes: walking down the ranking would let the veto pick the
        answer whatever the network learned (an untrained network's answers would then
        change 40 % of the recorded decisions, not 84 %).
        """
        left = shares.copy()
        left[1 + vetoed_address] = -1.0
        output = int(np.argmax(left))
        if output == 0:
            return None
        vetoed, distance = self._vetoed(output - 1, x, k, d2)
        if vetoed:
            self.stats.vetoes += 1
            return None
        rest = float(shares.sum() - shares[1 + vetoed_address])
        return output - 1, float(shares[output]) / rest, distance

    def store(self, features: np.ndarray, known: np.ndarray, focus_id: int = 0) -> int:
        """Supervised learning (step 4 of section 4.1): store a new object and retrain.

        The new address gets the looks of focus ``focus_id`` that show the same object as
        ``features`` (those within the acceptance distance of it, their unknown features
        completed from it, e.g. the weight measured at the end of the focus), plus
        ``features`` itself; then the network is retrained by replay.

        Args:
            features: F floats in [0, 1]; known: which of them are measured.
            focus_id: The focus whose looks to store with it (0: only ``features``).

        Returns:
            The new address: 0 for the first object, then 1, 2, ...

        Raises:
            MessageError: Wrong shape, a known feature not finite, or nothing known.
        """
        x, k = _validate(features, known, self._dim, self._config.features,
                         need_known=True)
        looks = self._focus_looks if focus_id and focus_id == self._focus_id else []
        xs, ks = self._same_object(looks, x, k)
        address = self._network.add_address()
        self._append(address, xs, ks, stored=True)
        self._retrain(focus=address)
        return address

    def store_many(self, features: np.ndarray, known: np.ndarray) -> list[int]:
        """Store several new objects, one look each, with one retraining (e.g. to preload).

        Args:
            features: (n, F) floats; known: (n, F) booleans.

        Returns:
            The n new addresses, in order.
        """
        rows = [_validate(f, k, self._dim, self._config.features, need_known=True)
                for f, k in zip(features, known, strict=True)]
        new: list[int] = []
        for x, k in rows:
            address = self._network.add_address()
            self._append(address, x[None], k[None], stored=True)
            new.append(address)
        if new:
            self._retrain(focus=new[0] if len(new) == 1 else -1)
        return new

    def handle(self, req: MemoryRequest) -> MatchResult:
        """Answer a request: MATCH -> :meth:`match`; STORE -> MatchResult(NEW, address, 1.0)."""
        if req.op == MemoryOp.STORE:
            return MatchResult(MatchOutcome.NEW,
                               self.store(req.features, req.known, req.focus_id), 1.0)
        if req.op == MemoryOp.MATCH:
            return self.match(req.features, req.known, req.final_trial, req.focus_id)
        raise MessageError(f"MemoryRequest {req.request_id}: unknown op {req.op!r}")

    def snapshot(self) -> MemorySnapshot:
        """Copy of everything that :meth:`save` writes."""
        weights = {k: v.detach().numpy().copy() for k, v in self._network.state_dict().items()}
        return MemorySnapshot(self._config.to_dict(), self._seed, self.size,
                              self._exemplars.copy(), self._known.copy(),
                              self._addresses.copy(), weights, self._stored.copy())

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
        if config.features != saved.features:
            raise MemoryFileError(
                f"{source}: a memory of {saved.features}-mode features "
                f"({len(snap.exemplars[0]) if len(snap.exemplars) else '?'} per look), but "
                f"this run uses the {config.features} mode; run with --features "
                f"{saved.features}, or give another memory file")
        for name in ARCHITECTURE_FIELDS:
            if getattr(config, name) != getattr(saved, name):
                raise MemoryFileError(
                    f"{source}: {name}={getattr(saved, name)} in the file but "
                    f"{getattr(config, name)} in the configuration; use the file's value "
                    "or start a new memory file")
        memory = cls(config, snap.seed)
        memory._network.resize(len(snap.addresses), snap.n_addresses)
        try:
            state = {k: torch.from_numpy(np.ascontiguousarray(v)) for k, v in snap.weights.items()}
            memory._network.load_state_dict(state, strict=True)
        except (RuntimeError, TypeError) as exc:
            raise MemoryFileError(f"{source}: network weights do not fit ({exc})") from exc
        memory._network.eval()
        memory._exemplars = np.asarray(snap.exemplars, np.float32).copy()
        memory._known = np.asarray(snap.known, bool).copy()
        memory._addresses = np.asarray(snap.addresses, np.int64).copy()
        memory._stored = np.asarray(snap.stored, bool).copy()
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
            config: Configuration to use (thresholds may differ from the file's); None
                uses the one stored in the file.

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

    def _keep_look(self, focus_id: int, x: np.ndarray, k: np.ndarray) -> None:
        if focus_id != self._focus_id:
            self._focus_id = int(focus_id)
            self._focus_looks = []
        if focus_id and not any(np.array_equal(x, fx) and np.array_equal(k, fk)
                                for fx, fk in self._focus_looks):
            self._focus_looks.append((x, k))

    def _same_object(self, looks: list[tuple[np.ndarray, np.ndarray]], x: np.ndarray,
                     k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The looks of a focus that show the object of (x, k), completed with what (x, k)
        knows, without duplicates, (x, k) last."""
        scale = np.asarray(self._config.feature_scale)
        kept: list[tuple[np.ndarray, np.ndarray]] = []
        for fx, fk in looks:
            # Unknown features are 0 in every validated look, so a completed look that
            # equals (x, k) or an earlier one is equal array for array. Two looks can
            # complete to one: a look before the haptic improvement, and the look after it
            # when that frame measured nothing new but W (its ROI cut by the retina's
            # edge). One copy is kept.
            cx, ck = np.where(fk, fx, x).astype(np.float32), fk | k
            d = _rms_z(cx[None], ck[None], x, k, scale, self._config.min_common_features,
                       self._config.feature_weight, self._config.z_cap, self._crease_gate)[0]
            if d <= self._config.identify_distance and not any(
                    np.array_equal(ck, ok) and np.array_equal(cx, ox)
                    for ox, ok in (*kept, (x, k))):
                kept.append((cx, ck))
        kept.append((x, k))
        return np.stack([lx for lx, _ in kept]), np.stack([lk for _, lk in kept])

    def _refine(self, address: int, x: np.ndarray, k: np.ndarray) -> None:
        """Add the current focus's looks of an identified object to its address.

        Each is written into a new hidden unit of the address (no retraining on the
        match's path; the next store's retraining includes the unit). Only a look that
        knows every feature the address knows, and that one of the address's *stored*
        looks (not an earlier refinement) accepts, is added: an address then never reaches
        further than one acceptance radius beyond what was stored, so identifications
        cannot chain it into another object.
        """
        mine = self._addresses == address
        if np.any(self._known[mine].any(axis=0) & ~k):
            return
        cfg = self._config
        looks = self._focus_looks if self._focus_looks else [(x, k)]
        origin = mine & self._stored
        ox, ok = self._exemplars[origin], self._known[origin]
        held = int(np.count_nonzero(mine))
        scale = np.asarray(cfg.feature_scale)
        added = 0
        xs, ks = self._same_object(looks, x, k)
        for fx, fk in zip(xs, ks, strict=True):
            if held + added >= cfg.refine_looks:
                break
            if self.find_exact(fx, fk) is not None:
                continue
            d = _rms_z(ox, ok, fx, fk, scale, cfg.min_common_features, cfg.feature_weight,
                       cfg.z_cap, self._crease_gate)
            if d.size and d.min() <= cfg.identify_distance:
                self._append(address, fx[None], fk[None], stored=False)
                added += 1
        # No retraining here: a unit answers as soon as its look is written in (the match
        # stays one forward pass), and the retraining after the next store includes it.
        self.stats.refinements += added

    def _count(self, outcome: MatchOutcome) -> None:
        if outcome is MatchOutcome.IDENTIFIED:
            self.stats.identified += 1
        elif outcome is MatchOutcome.NEW:
            self.stats.new += 1
        else:
            self.stats.undetermined += 1

    def _append(self, address: int, xs: np.ndarray, ks: np.ndarray, stored: bool) -> None:
        xs = np.where(ks, xs, 0.0).astype(np.float32)
        self._exemplars = np.vstack([self._exemplars, xs])
        self._known = np.vstack([self._known, ks])
        self._addresses = np.append(self._addresses, np.full(len(xs), address, np.int64))
        self._stored = np.append(self._stored, np.full(len(xs), stored))
        self._network.add_units(xs, ks, address)
        self.revision += 1

    def _retrain(self, focus: int) -> None:
        rng = np.random.default_rng([self._seed, len(self._addresses), self.size])
        self.last_train_steps = train_replay(
            self._network, self._exemplars, self._known, self._addresses, focus,
            self._config, rng)

    def _check_address(self, address: int) -> None:
        if not 0 <= address < self.size:
            raise IndexError(f"address {address} outside [0, {self.size})")


def _rms_z(xs: np.ndarray, ks: np.ndarray, x: np.ndarray, k: np.ndarray, scale: np.ndarray,
           min_common: int, weight: tuple[float, ...], z_cap: float = 0.0,
           crease_gate: tuple[int, float, np.ndarray] | None = None) -> np.ndarray:
    """Weighted RMS over the common known features of z_f = (x_f - xs_f) / (sqrt(2)
    scale_f): sqrt(sum w_f z_f^2 / sum w_f); inf with fewer than ``min_common`` common
    features (or none of positive weight). ``crease_gate`` (crease column, least crease,
    features): those features are left out where both looks are creased."""
    common = ks & k
    if crease_gate is not None and k[crease_gate[0]] and x[crease_gate[0]] >= crease_gate[1]:
        # The query is creased: leave the features out against the creased looks.
        col, least, unused = crease_gate
        common = uncreased_common(common, creased_looks(xs, ks, col, least),
                                  np.ones(len(xs), bool), unused)
    n = common.sum(axis=1)
    d = rms_z(xs - x, common, scale, np.asarray(weight), z_cap)
    return np.where(n >= min_common, d, np.inf)


def _validate(
    features: np.ndarray, known: np.ndarray, dim: int, mode: str, need_known: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Checked copies: float32 features clipped to [0, 1] (0 where unknown), bool mask."""
    x = np.asarray(features, np.float64).reshape(-1)
    k = np.asarray(known).reshape(-1)
    if x.shape != (dim,) or k.shape != (dim,):
        raise MessageError(
            f"features/known must have {dim} entries (a memory of the {mode} feature "
            f"mode), got {x.size} and {k.size}")
    k = k.astype(bool)
    if not np.all(np.isfinite(x[k])):
        raise MessageError("a known feature is NaN or infinite")
    if need_known and not k.any():
        raise MessageError("cannot store a pattern with no known feature")
    return np.where(k, np.clip(np.nan_to_num(x), 0.0, 1.0), 0.0).astype(np.float32), k
