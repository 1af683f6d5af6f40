"""The back-propagation network of the associative memory, with a winner-take-all output.

Section 2 of the paper: ROI features are "a pattern activation code in a central associative
memory which is a BP neural-network with a winner-take-all mechanism. That network matches
the pattern to an address in the long term memory". Step 4 of section 4.1: a supervised
learning module "stores a new set of features in the long-term memory and re-trains the BP
network".

Input coding: a feature that is not measured yet (the weight W before a haptic
improvement) must count as unknown, not as zero. The input is therefore the feature vector
with unknown entries zeroed, followed by the ``known`` mask itself (2 * FEATURE_DIM inputs):
the network can tell "W = 0" from "W not measured".

Output: one unit per long-term-memory address. The memory starts empty; each store adds an
output unit (the old units keep their weights) and retrains with replay of every stored
exemplar, so old recalls stay intact (see docs/memory.md).
"""

from __future__ import annotations

import contextlib
import math
import warnings
from collections.abc import Iterator

import numpy as np
import torch
from torch import nn

from roger_common.types import FEATURE_DIM, FEATURE_NAMES
from roger_memory.config import MemoryConfig

#: Inputs of the network: masked features then the known mask.
INPUT_DIM: int = 2 * FEATURE_DIM


def encode(features: np.ndarray, known: np.ndarray) -> np.ndarray:
    """Network input for one or many feature vectors.

    Args:
        features: (FEATURE_DIM,) or (n, FEATURE_DIM) floats in [0, 1].
        known: Same shape, booleans; False where a feature is not measured.

    Returns:
        (n, INPUT_DIM) float32: features with unknown entries zeroed, then the mask.
    """
    x = np.atleast_2d(np.asarray(features, np.float32))
    k = np.atleast_2d(np.asarray(known, bool))
    return np.concatenate([np.where(k, x, 0.0), k], axis=1).astype(np.float32)


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

    The network is tiny (a 128 x 16 batch, 64 hidden units): with two or more threads every
    operation pays for waking and joining the pool, which made a replay step about ten
    times slower (6.6 ms instead of 0.6 ms on a 2-core machine, docs/performance.md). One
    thread is also what the memory node uses, so the graph and the in-process core loop
    compute the same floats.
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
        logits: (n_addresses,) output activations for one pattern.

    Returns:
        (winner, confidence, shares): the index of the largest output, its softmax share
        in [0, 1] (1 when the winner takes all), and every unit's share.
    """
    shares = torch.softmax(logits, dim=-1)
    winner = int(torch.argmax(shares))
    return winner, float(shares[winner]), shares


class AssociativeNetwork(nn.Module):
    """Feed-forward BP network: INPUT_DIM -> tanh hidden layers -> one unit per address.

    Args:
        hidden_sizes: Units of each hidden layer.
        generator: Seeded torch generator for the initial weights (no global RNG).
    """

    def __init__(self, hidden_sizes: tuple[int, ...], generator: torch.Generator) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        width = INPUT_DIM
        for h in hidden_sizes:
            linear = _new_linear(width, h, generator)
            layers += [linear, nn.Tanh()]
            width = h
        self.hidden = nn.Sequential(*layers)
        self.output = _new_linear(width, 0, generator)

    @property
    def n_addresses(self) -> int:
        """Number of output units, one per long-term-memory address."""
        return self.output.out_features

    def add_address(self, generator: torch.Generator) -> int:
        """Append one output unit; the existing units keep their weights.

        Returns:
            The new address (index of the new unit).
        """
        old = self.output
        new = _new_linear(old.in_features, old.out_features + 1, generator)
        with torch.no_grad():
            new.weight[: old.out_features] = old.weight
            new.bias[: old.out_features] = old.bias
            # Start the new unit below the others so it does not steal their patterns
            # before replay has shaped it.
            new.bias[old.out_features] = old.bias.min() if old.out_features else 0.0
        self.output = new
        return old.out_features

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Output activations (logits), shape (n, n_addresses), for encoded inputs x."""
        return self.output(self.hidden(x))

    @torch.no_grad()
    def recall(self, features: np.ndarray, known: np.ndarray) -> tuple[int, float, np.ndarray]:
        """Winner-take-all answer for one pattern.

        Returns:
            (winner, confidence, shares) as in :func:`winner_take_all`; shares is numpy.
        """
        if self.n_addresses == 0:
            return -1, 0.0, np.zeros(0, np.float32)
        with one_thread():
            logits = self(torch.from_numpy(encode(features, known)))[0]
            winner, confidence, shares = winner_take_all(logits)
        return winner, confidence, shares.numpy()

    @torch.no_grad()
    def shares(self, features: np.ndarray, known: np.ndarray) -> np.ndarray:
        """Softmax shares of every unit for many patterns at once, shape (n, n_addresses)."""
        with one_thread():
            return torch.softmax(self(torch.from_numpy(encode(features, known))),
                                 dim=1).numpy()


def _new_linear(n_in: int, n_out: int, generator: torch.Generator) -> nn.Linear:
    """A linear layer initialised from ``generator`` only (torch's global RNG is untouched).

    Built on the meta device first, because nn.Linear's own init draws from the global RNG.
    """
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", "Initializing zero-element", UserWarning)
        linear = nn.Linear(n_in, n_out, device="meta").to_empty(device="cpu")
    bound = 1.0 / math.sqrt(max(linear.in_features, 1))
    with torch.no_grad():
        linear.weight.uniform_(-bound, bound, generator=generator)
        linear.bias.uniform_(-bound, bound, generator=generator)
    return linear


def train_replay(
    network: AssociativeNetwork,
    exemplars: np.ndarray,
    known: np.ndarray,
    addresses: np.ndarray,
    focus: int,
    config: MemoryConfig,
    rng: np.random.Generator,
) -> int:
    """Supervised learning module: retrain the network by replaying the stored exemplars.

    Each step draws ``batch_size`` exemplars, ``new_fraction`` of them from the address
    ``focus`` (the one just stored) and the rest uniformly from all, adds Gaussian noise and
    turns the maskable features unknown at random, then takes one Adam step on the
    cross-entropy of the winner-take-all output. After ``train_steps`` steps, training goes
    on in blocks of ``check_every`` steps until every exemplar, with its own mask, wins with
    a share >= ``recall_confidence``, or ``max_train_steps`` is reached.

    Args:
        network: The network to train in place.
        exemplars: (n, FEATURE_DIM) stored feature vectors.
        known: (n, FEATURE_DIM) their known masks.
        addresses: (n,) address of each exemplar.
        focus: Address to oversample (the newest); -1 for none.
        config: Training parameters.
        rng: Seeded generator for batches, noise and masks.

    Returns:
        Number of steps taken.
    """
    with one_thread():
        return _train_replay(network, exemplars, known, addresses, focus, config, rng)


def _train_replay(network: AssociativeNetwork, exemplars: np.ndarray, known: np.ndarray,
                  addresses: np.ndarray, focus: int, config: MemoryConfig,
                  rng: np.random.Generator) -> int:
    n = len(exemplars)
    focus_idx = np.flatnonzero(addresses == focus)
    maskable = np.array([name in config.maskable_features for name in FEATURE_NAMES])
    x_all = np.asarray(exemplars, np.float32)
    k_all = np.asarray(known, bool)
    y_all = torch.from_numpy(np.asarray(addresses, np.int64))
    optimizer = torch.optim.Adam(network.parameters(), lr=config.learning_rate)
    n_focus = round(config.batch_size * config.new_fraction) if len(focus_idx) else 0
    steps = 0
    network.train()
    block = config.train_steps
    while steps < config.max_train_steps:
        for _ in range(min(block, config.max_train_steps - steps)):
            idx = np.concatenate([
                rng.choice(focus_idx, n_focus) if n_focus else np.zeros(0, np.int64),
                rng.integers(0, n, config.batch_size - n_focus),
            ])
            x = x_all[idx] + rng.normal(0.0, config.train_noise_std, (len(idx), FEATURE_DIM))
            drop = maskable & (rng.random((len(idx), FEATURE_DIM)) < config.unknown_feature_prob)
            k = k_all[idx] & ~drop
            inputs = torch.from_numpy(encode(np.clip(x, 0.0, 1.0), k))
            loss = nn.functional.cross_entropy(network(inputs), y_all[idx])
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            steps += 1
        own = network.shares(x_all, k_all)[np.arange(n), addresses]
        if own.min() >= config.recall_confidence:
            break
        block = config.check_every
    network.eval()
    return steps
