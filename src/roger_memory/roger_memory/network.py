"""The back-propagation network of the associative memory, with a winner-take-all output.

Section 2 of the paper: ROI features are "a pattern activation code in a central associative
memory which is a BP neural-network with a winner-take-all mechanism. That network matches
the pattern to an address in the long term memory". Step 4 of section 4.1: a supervised
learning module "stores a new set of features in the long-term memory and re-trains the BP
network".

The network must also say "none of them": after all trials an object that matches no
address is new. A tanh network's winner is as confident far from every stored pattern as
near one (nothing in it measures "near"), so this one has a radial hidden layer:

* hidden layer: one unit per stored look (its centre: the look's features, written in by
  the store, then trained). Its activation is the weighted mean squared z over the
  features known both in the input and in the look, sum w_f z_f^2 / sum w_f,
  z_f = (x_f - c_f) / (sqrt(2) sigma_f), with one trained scale sigma_f per feature
  (shared by all units) and one calibrated information weight w_f per feature (how much
  agreement in that feature tells; MemoryConfig.feature_weight). A unit that shares fewer than
  ``min_common_features`` known features with the input is silent. Unknown features (W
  before a haptic improvement) are left out, never taken as zero;
* output layer: one unit per long-term-memory address, -gain / 2 * (its nearest look's
  activation) + bias, and one *novel* unit, -gain / 2 * tau^2 (tau: the acceptance
  distance, trained);
* winner-take-all over the 1 + n_addresses outputs; the winner's softmax share is the
  network's confidence. The novel unit wins when no stored look is within about tau.

All parameters (centres, scales, tau, gain, biases) are trained by back-propagation of the
cross-entropy of the winner-take-all output (see :func:`train_replay`).
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterator

import numpy as np
import torch
from torch import nn

from roger_common.types import TOUCH_FEATURE_NAMES, WEIGHT_INDEX, feature_names
from roger_memory.config import MemoryConfig

#: Activation standing in for "no unit can answer" (finite, so that gradients stay finite).
SILENT: float = 1.0e4

_warmed_up = False


def warm_up_optimizer() -> None:
    """Take one Adam step on a throwaway parameter, once per process.

    torch's first optimizer step imports ``torch._dynamo``: 1.3 s on the 2-core machine.
    Paid here, when a memory is built, instead of at the first store, where it stalled a
    running graph for that long (and cost the 204-cycle benchmark ~6 ms per cycle).
    """
    global _warmed_up
    if _warmed_up:
        return
    p = torch.nn.Parameter(torch.zeros(1))
    optimizer = torch.optim.Adam([p])
    p.sum().backward()
    optimizer.step()
    _warmed_up = True


@contextlib.contextmanager
def one_thread() -> Iterator[None]:
    """Run torch on one intra-op thread inside the block, then restore the thread count.

    The network is tiny: with two or more threads every operation pays for waking and
    joining the pool, which made a replay step about ten times slower on a 2-core machine
    (docs/performance.md). One thread is also what the memory node uses, so the graph and
    the in-process core loop compute the same floats.
    """
    threads = torch.get_num_threads()
    if threads == 1:
        yield
        return
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


def winner_take_all(logits: torch.Tensor) -> tuple[int, float, torch.Tensor]:
    """Winner-take-all over the output units.

    Args:
        logits: (n_outputs,) output activations for one pattern.

    Returns:
        (winner, confidence, shares): the index of the largest output, its softmax share
        in [0, 1] (1 when the winner takes all), and every unit's share.
    """
    shares = torch.softmax(logits, dim=-1)
    winner = int(torch.argmax(shares))
    return winner, float(shares[winner]), shares


@torch.no_grad()
def _fill(t: torch.Tensor, generator: torch.Generator, low: float, high: float) -> None:
    t.uniform_(low, high, generator=generator)


class AssociativeNetwork(nn.Module):
    """Radial BP network: stored looks -> one output per address plus a novel output.

    Output 0 is the novel unit; output ``1 + a`` is address ``a``.

    Args:
        feature_scale: Initial sigma_f per feature (MemoryConfig.feature_scale).
        identify_distance: Initial tau (MemoryConfig.identify_distance).
        min_common_features: Fewest common known features for a unit to answer.
        feature_weight: Weight w_f of each feature's z^2 (MemoryConfig.feature_weight;
            None: all 1). A calibrated constant, not trained, and not saved with the
            weights (it comes with the configuration).
    """

    def __init__(self, feature_scale: tuple[float, ...], identify_distance: float,
                 min_common_features: int,
                 feature_weight: tuple[float, ...] | None = None,
                 z_cap: float = 0.0) -> None:
        super().__init__()
        self.min_common_features = int(min_common_features)
        #: Largest |z| one feature contributes (MemoryConfig.z_cap; 0: none).
        self.z_cap = float(z_cap)
        #: Length of the feature vectors (the mode's, ``roger_common.types.feature_dim``).
        self.dim = len(feature_scale)
        weight = [1.0] * self.dim if feature_weight is None else list(feature_weight)
        self.register_buffer("feature_weight", torch.tensor(weight, dtype=torch.float32),
                             persistent=False)
        self.feature_weight: torch.Tensor
        self.log_scale = nn.Parameter(torch.log(torch.tensor(feature_scale, dtype=torch.float32)))
        self.log_tau = nn.Parameter(torch.tensor(math.log(identify_distance), dtype=torch.float32))
        self.log_gain = nn.Parameter(torch.zeros(()))
        # A centre is its stored look plus a trained shift in units of the calibrated
        # repeat noise (sqrt(2) sigma_f): Adam's steps are then alike in every feature,
        # where in feature units they would move a precise feature (T, D: sigma ~ 0.005)
        # by several sigma per step.
        self.register_buffer("step", np.sqrt(2.0) * torch.tensor(feature_scale,
                                                                   dtype=torch.float32))
        self.register_buffer("stored", torch.zeros(0, self.dim))
        self.shift = nn.Parameter(torch.zeros(0, self.dim))
        self.bias = nn.Parameter(torch.zeros(0))
        self.register_buffer("unit_known", torch.zeros(0, self.dim, dtype=torch.bool))
        self.register_buffer("unit_address", torch.zeros(0, dtype=torch.long))
        self.step: torch.Tensor
        self.stored: torch.Tensor
        self.unit_known: torch.Tensor
        self.unit_address: torch.Tensor
        #: Between an input and a unit whose looks both found a crease (column, least
        #: value), the features of the mask count not (MemoryConfig.creased_unused;
        #: ``set_crease_gate``). None: every common feature counts.
        self.crease_gate: tuple[int, float, torch.Tensor] | None = None

    def set_crease_gate(self, crease_index: int | None, crease_min: float,
                        unused: np.ndarray | None) -> None:
        """Leave the features of ``unused`` out between two looks whose crease (column
        ``crease_index``) is known and at least ``crease_min`` (None or no feature: off)."""
        if crease_index is None or unused is None or not np.any(unused):
            self.crease_gate = None
        else:
            self.crease_gate = (int(crease_index), float(crease_min),
                                torch.from_numpy(np.asarray(unused, bool).copy()))

    @property
    def n_addresses(self) -> int:
        """Number of address outputs (the novel unit not counted)."""
        return int(self.bias.shape[0])

    @property
    def n_units(self) -> int:
        """Number of hidden units (stored looks)."""
        return int(self.stored.shape[0])

    @property
    def centres(self) -> torch.Tensor:
        """The units' centres, (n_units, dim): stored look + trained shift."""
        return self.stored + self.shift * self.step

    @property
    def scale(self) -> np.ndarray:
        """The trained sigma_f, per feature."""
        return torch.exp(self.log_scale).detach().numpy().copy()

    @property
    def tau(self) -> float:
        """The trained acceptance distance."""
        return float(torch.exp(self.log_tau.detach()))

    @property
    def gain(self) -> float:
        """The trained gain of the output units."""
        return float(torch.exp(self.log_gain.detach()))

    def add_address(self) -> int:
        """Append one address output (bias 0); the existing outputs keep their weights.

        Returns:
            The new address.
        """
        with torch.no_grad():
            self.bias = nn.Parameter(torch.cat([self.bias.detach(), torch.zeros(1)]))
        return self.n_addresses - 1

    def add_units(self, features: np.ndarray, known: np.ndarray, address: int) -> None:
        """Append hidden units centred on looks of ``address`` (the store writes them in)."""
        x = torch.from_numpy(np.asarray(features, np.float32).reshape(-1, self.dim))
        k = torch.from_numpy(np.asarray(known, bool).reshape(-1, self.dim))
        with torch.no_grad():
            self.shift = nn.Parameter(torch.cat([self.shift.detach(), torch.zeros_like(x)]))
        self.stored = torch.cat([self.stored, x])
        self.unit_known = torch.cat([self.unit_known, k])
        self.unit_address = torch.cat([self.unit_address,
                                       torch.full((len(x),), int(address), dtype=torch.long)])

    def resize(self, n_units: int, n_addresses: int) -> None:
        """Empty parameters of the given shape (to load a saved state_dict into)."""
        with torch.no_grad():
            self.shift = nn.Parameter(torch.zeros(n_units, self.dim))
            self.bias = nn.Parameter(torch.zeros(n_addresses))
        self.stored = torch.zeros(n_units, self.dim)
        self.unit_known = torch.zeros(n_units, self.dim, dtype=torch.bool)
        self.unit_address = torch.zeros(n_units, dtype=torch.long)

    def untrained_copy(self, generator: torch.Generator) -> AssociativeNetwork:
        """A network of the same shape whose parameters were never trained (for ablations):
        centres drawn uniformly in the feature range, scales, tau and gain drawn around 1,
        biases around 0. The units keep their known masks and addresses (the shape)."""
        net = AssociativeNetwork(tuple([1.0] * self.dim), 1.0, self.min_common_features,
                                 tuple(self.feature_weight.tolist()), self.z_cap)
        net.resize(self.n_units, self.n_addresses)
        net.unit_known = self.unit_known.clone()
        net.unit_address = self.unit_address.clone()
        net.crease_gate = self.crease_gate
        _fill(net.stored, generator, 0.0, 1.0)
        _fill(net.log_scale.data, generator, -0.1, 0.1)
        _fill(net.log_tau.data, generator, -0.1, 0.1)
        _fill(net.log_gain.data, generator, -0.1, 0.1)
        _fill(net.bias.data, generator, -0.1, 0.1)
        net.eval()
        return net

    def unit_distances(self, x: torch.Tensor, k: torch.Tensor) -> torch.Tensor:
        """Weighted mean squared z of inputs to every unit, (n, n_units); SILENT where too few
        features are common, and where the input's weight is measured and the unit's is
        not (a look of an object never weighed cannot vouch for a weighed one: on sight
        alone it takes in objects of every weight; docs/memory.md).

        Computed as three matrix products, so a match costs one small product per feature
        set whatever the number of units.
        """
        inv = 0.5 * self.feature_weight * torch.exp(-2.0 * self.log_scale)   # w / (2 sigma^2)
        kf = k.to(x.dtype)
        m = self.unit_known.to(x.dtype)
        c = self.centres * m
        if self.z_cap > 0 or self.crease_gate is not None:
            # Each feature's z^2 capped (a robust distance), or some left out between two
            # creased looks: one feature per pair of inputs and units, since neither
            # factors into products.
            z2 = (x[:, None, :] - c[None, :, :]) ** 2 * (0.5 * torch.exp(-2.0 * self.log_scale))
            if self.z_cap > 0:
                z2 = z2.clamp_max(self.z_cap * self.z_cap)
            common = kf[:, None, :] * m[None, :, :]
            gated = False
            if self.crease_gate is not None:
                col, least, unused = self.crease_gate
                creased_in = k[:, col] & (x[:, col] >= least)
                both = creased_in[:, None] & (self.unit_known[:, col]
                                              & (self.stored[:, col] >= least))[None, :]
                if bool(creased_in.any()) and bool(both.any()):
                    common = common * ~(both[:, :, None] & unused[None, None, :])
                    gated = True
            sq = (z2 * common * self.feature_weight).sum(dim=2)
            if gated:
                n = common.sum(dim=2)
                wn = (common * self.feature_weight).sum(dim=2)
            else:
                n = kf @ m.T
                wn = (kf * self.feature_weight) @ m.T
        else:
            kx = kf * x
            sq = ((kx * x) * inv) @ m.T - 2.0 * (kx * inv) @ c.T + (kf * inv) @ (c * c).T
            n = kf @ m.T
            wn = (kf * self.feature_weight) @ m.T
        d2 = sq.clamp_min(0.0) / wn.clamp_min(1e-6)
        untouched = k[:, WEIGHT_INDEX:WEIGHT_INDEX + 1] & ~self.unit_known[:, WEIGHT_INDEX]
        return torch.where((n >= self.min_common_features) & (wn > 0) & ~untouched,
                           d2.clamp_max(SILENT), torch.full_like(d2, SILENT))

    def address_distances(self, d2: torch.Tensor) -> torch.Tensor:
        """Per address, the activation of its nearest unit: (n, n_addresses)."""
        out = torch.full((d2.shape[0], self.n_addresses), SILENT, dtype=d2.dtype)
        index = self.unit_address.unsqueeze(0).expand_as(d2)
        return out.scatter_reduce(1, index, d2, reduce="amin", include_self=True)

    def forward(self, x: torch.Tensor, k: torch.Tensor) -> torch.Tensor:
        """Output activations (logits), (n, 1 + n_addresses): novel unit first."""
        gain = torch.exp(self.log_gain)
        per_address = self.address_distances(self.unit_distances(x, k))
        addresses = -0.5 * gain * per_address + self.bias
        novel = (-0.5 * gain * torch.exp(2.0 * self.log_tau)).expand(x.shape[0], 1)
        return torch.cat([novel, addresses], dim=1)

    @torch.no_grad()
    def recall(self, features: np.ndarray, known: np.ndarray
               ) -> tuple[int, float, np.ndarray, np.ndarray]:
        """Winner-take-all answer for one pattern.

        Returns:
            (winner, confidence, shares, unit_d2): the winning output (0: novel, 1 + a:
            address a), its share, every output's share, and every unit's activation.
        """
        with one_thread():
            x = torch.from_numpy(np.asarray(features, np.float32).reshape(1, self.dim))
            k = torch.from_numpy(np.asarray(known, bool).reshape(1, self.dim))
            d2 = self.unit_distances(x, k)
            gain = torch.exp(self.log_gain)
            addresses = -0.5 * gain * self.address_distances(d2) + self.bias
            novel = (-0.5 * gain * torch.exp(2.0 * self.log_tau)).reshape(1, 1)
            logits = torch.cat([novel, addresses], dim=1)[0]
            winner, confidence, shares = winner_take_all(logits)
        return winner, confidence, shares.numpy(), d2[0].numpy()

    @torch.no_grad()
    def shares(self, features: np.ndarray, known: np.ndarray) -> np.ndarray:
        """Softmax shares of every output for many patterns, (n, 1 + n_addresses)."""
        with one_thread():
            x = torch.from_numpy(np.asarray(features, np.float32).reshape(-1, self.dim))
            k = torch.from_numpy(np.asarray(known, bool).reshape(-1, self.dim))
            return torch.softmax(self(x, k), dim=1).numpy()


def student_t_noise(rng: np.random.Generator, shape: tuple[int, ...], dof: float
                    ) -> np.ndarray:
    """Multivariate Student-t draws (one scale per row): Gaussian / sqrt(chi2_dof / dof).

    The robot's repeat looks have heavy tails (a look now and then is far off in every
    feature at once); one common scale per row reproduces that.
    """
    g = rng.standard_normal(shape)
    w = rng.chisquare(dof, (shape[0],) + (1,) * (len(shape) - 1)) / dof
    return g / np.sqrt(w)


def train_replay(
    network: AssociativeNetwork,
    exemplars: np.ndarray,
    known: np.ndarray,
    addresses: np.ndarray,
    focus: int,
    config: MemoryConfig,
    rng: np.random.Generator,
) -> int:
    """Supervised learning module: retrain the network by replaying the stored looks.

    Each step draws ``batch_size`` samples. Repeats: stored looks (``new_fraction`` of
    them from the address ``focus``, the rest uniformly from all), moved by the robot's
    calibrated repeat noise (per feature sqrt(2) sigma_f times a Student-t of
    ``noise_dof`` degrees of freedom) with the maskable features (W) turned unknown at
    random; their target is their address. Novel samples (``novel_fraction`` of the
    batch): stored looks moved by a random offset whose weighted RMS z-distance lies between
    ``novel_near`` and ``novel_far`` times the calibrated tau; their target is the novel
    unit. One Adam step on the cross-entropy of the winner-take-all output, plus a pull of
    every centre towards its stored look, of the scales and tau towards the calibration
    and of the gain and biases towards 1 and 0 (``prior_weight``). Looks with fewer than
    ``min_common_features`` known features are left out (their unit never answers).
    After ``train_steps`` steps, training goes on in blocks of ``check_every`` until every
    stored look, with its own mask, wins for its address with a share >=
    ``recall_confidence`` (addresses that answer it as well as its own count with it), or
    ``max_train_steps`` is reached.

    Args:
        network: The network to train in place.
        exemplars: (n, dim) stored looks (the units' stored values).
        known: (n, dim) their known masks.
        addresses: (n,) address of each look.
        focus: Address to oversample (the newest); -1 for none.
        config: Training parameters and the calibration.
        rng: Seeded generator for batches, noise and masks.

    Returns:
        Number of steps taken.
    """
    with one_thread():
        return _train_replay(network, exemplars, known, addresses, focus, config, rng)


def _train_replay(network: AssociativeNetwork, exemplars: np.ndarray, known: np.ndarray,
                  addresses: np.ndarray, focus: int, config: MemoryConfig,
                  rng: np.random.Generator) -> int:
    x_all = np.asarray(exemplars, np.float32)
    k_all = np.asarray(known, bool)
    dim = x_all.shape[1]
    # A look with too few known features can never answer (its unit is silent): it is
    # neither replayed nor checked, else training would bend every weight to recall it.
    usable = np.flatnonzero(k_all.sum(axis=1) >= config.min_common_features)
    if usable.size == 0:
        return 0
    focus_idx = usable[addresses[usable] == focus]
    names = feature_names(config.features)
    maskable = np.array([name in config.maskable_features for name in names])
    # Touch's features share W's draw (one haptic improvement measures them all); any
    # other maskable feature (the fovea's O) has a draw of its own.
    draw_column = np.array([WEIGHT_INDEX if name in TOUCH_FEATURE_NAMES else i
                            for i, name in enumerate(names)])
    y_all = np.asarray(addresses, np.int64) + 1
    prior_scale = torch.log(torch.tensor(config.feature_scale, dtype=torch.float32))
    prior_tau = torch.tensor(math.log(config.identify_distance), dtype=torch.float32)
    sigma = np.sqrt(2.0) * np.asarray(config.feature_scale)
    optimizer = torch.optim.Adam(network.parameters(), lr=config.learning_rate)
    n_novel = round(config.batch_size * config.novel_fraction)
    n_repeat = config.batch_size - n_novel
    n_focus = round(n_repeat * config.new_fraction) if len(focus_idx) else 0
    steps = 0
    network.train()
    block = config.train_steps
    while steps < config.max_train_steps:
        for _ in range(min(block, config.max_train_steps - steps)):
            idx = np.concatenate([
                rng.choice(focus_idx, n_focus) if n_focus else np.zeros(0, np.int64),
                rng.choice(usable, n_repeat - n_focus)])
            noise = student_t_noise(rng, (len(idx), dim), config.noise_dof) * sigma
            x = x_all[idx] + noise
            # The maskable features turn unknown as they become known: touch's together
            # (W's column of one draw per sample), the fovea's on its own column (the
            # paper mode's draws unchanged).
            draw = rng.random((len(idx), dim))[:, draw_column]
            drop = maskable & (draw < config.unknown_feature_prob)
            k = k_all[idx] & ~drop
            k = np.where((k.sum(axis=1) >= config.min_common_features)[:, None], k, k_all[idx])
            y = y_all[idx]
            if n_novel:
                nov = rng.choice(usable, n_novel)
                kn = k_all[nov]
                offset = novel_offsets(rng, kn, config) * sigma
                x = np.concatenate([x, x_all[nov] + offset])
                k = np.concatenate([k, kn])
                y = np.concatenate([y, np.zeros(n_novel, np.int64)])
            inputs = torch.from_numpy(np.clip(x, 0.0, 1.0).astype(np.float32))
            logits = network(inputs, torch.from_numpy(k))
            loss = nn.functional.cross_entropy(logits, torch.from_numpy(y))
            pull = (network.shift ** 2).sum(dim=1).mean()
            prior = ((network.log_scale - prior_scale) ** 2).mean() \
                + (network.log_tau - prior_tau) ** 2 + network.log_gain ** 2 \
                + (network.bias ** 2).mean()
            loss = loss + config.prior_weight * (pull + prior)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            steps += 1
        if _recalled(network, x_all[usable], k_all[usable], y_all[usable],
                     config.recall_confidence):
            break
        block = config.check_every
    network.eval()
    return steps


def novel_offsets(rng: np.random.Generator, known: np.ndarray, config: MemoryConfig
                  ) -> np.ndarray:
    """Offsets of the replay's synthetic novel samples from their stored looks, in z units
    (multiply by sqrt(2) sigma_f for feature units): a random direction over each look's
    known features, at a weighted RMS z-distance drawn uniformly between ``novel_near`` and
    ``novel_far`` times tau, measured as the network measures it.

    With a cap on each feature's |z| (``z_cap``, the extended mode), an offset's distance
    stops growing once its features reach the cap, and never exceeds the cap itself. The
    radius is drawn as without a cap, and one the capped distance cannot reach is set to
    the farthest it can (0.99 z_cap; 1.9 tau in the extended mode); each offset is then
    stretched (bisection) until its capped distance is that radius. So within reach the
    novel samples are as dense per unit of distance as the paper mode's, and the rest lie
    at the far end, where they teach "far is novel" and move no boundary near tau.
    Two earlier draws taught the extended network a boundary inside the calibration's:
    the radius in the uncapped distance (9 % of the novel samples then lay within tau
    once capped) and the radius drawn only over the reachable [tau, 1.6 tau] (three times
    the paper mode's density there); docs/memory.md, "Novel samples under the cap".

    Args:
        rng: The replay's generator.
        known: (n, F) known masks of the looks the samples start from.
        config: The memory's configuration (weights, tau, cap, novel_near/far).

    Returns:
        (n, F) offsets, 0 on unknown features.
    """
    n, dim = known.shape
    weight = np.asarray(config.feature_weight)
    direction = rng.standard_normal((n, dim)) * known
    wk = np.maximum((weight * known).sum(axis=1), 1e-9)
    norm = np.sqrt((weight * direction ** 2).sum(axis=1) / wk)
    unit = direction / np.maximum(norm, 1e-9)[:, None]
    tau = config.identify_distance
    if config.z_cap <= 0:
        radius = np.asarray(tau * rng.uniform(config.novel_near, config.novel_far, n))
        return unit * radius[:, None]
    cap2 = config.z_cap * config.z_cap
    radius = np.minimum(tau * rng.uniform(config.novel_near, config.novel_far, n),
                        0.99 * config.z_cap)

    def capped(stretch: np.ndarray) -> np.ndarray:
        z2 = np.minimum((unit * stretch[:, None]) ** 2, cap2)
        return np.sqrt((weight * z2).sum(axis=1) / wk)

    lo, hi = np.zeros(n), radius.copy()
    for _ in range(64):  # grow hi until it reaches the radius (monotone in the stretch)
        short = capped(hi) < radius
        if not short.any():
            break
        hi = np.where(short, hi * 2.0, hi)
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        below = capped(mid) < radius
        lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
    return unit * hi[:, None]


def _recalled(network: AssociativeNetwork, x: np.ndarray, k: np.ndarray, y: np.ndarray,
              confidence: float) -> bool:
    """Every look, with its own mask, wins for its address with ``confidence`` of the
    share, counting as one the addresses that answer it as well as its own (a look stored
    under two addresses cannot be told apart, and training must not try)."""
    shares = network.shares(x, k)
    own = shares[np.arange(len(y)), y]
    tied = shares[:, 1:] >= own[:, None] * (1.0 - 1e-3)
    return bool(np.all((shares[:, 1:] * tied).sum(axis=1) >= confidence))
