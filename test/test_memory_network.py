"""Unit tests of the BP network with winner-take-all and of MemoryConfig."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from roger_common.errors import ConfigError
from roger_common.types import FEATURE_DIM, WEIGHT_INDEX
from roger_memory.config import MemoryConfig
from roger_memory.network import (
    INPUT_DIM,
    AssociativeNetwork,
    encode,
    train_replay,
    winner_take_all,
)

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _net(seed: int = 0, addresses: int = 0) -> AssociativeNetwork:
    net = AssociativeNetwork(MemoryConfig().hidden_sizes, torch.Generator().manual_seed(seed))
    for a in range(addresses):
        net.add_address(torch.Generator().manual_seed(seed + 100 + a))
    return net


def test_encode_tells_unknown_from_zero() -> None:
    x = np.full(FEATURE_DIM, 0.5, np.float32)
    x[WEIGHT_INDEX] = 0.7
    known = np.ones(FEATURE_DIM, bool)
    unknown_w = known.copy()
    unknown_w[WEIGHT_INDEX] = False
    zero_w = x.copy()
    zero_w[WEIGHT_INDEX] = 0.0

    enc_unknown = encode(x, unknown_w)
    enc_zero = encode(zero_w, known)

    assert enc_unknown.shape == (1, INPUT_DIM)
    assert enc_unknown[0, WEIGHT_INDEX] == 0.0
    assert enc_unknown[0, FEATURE_DIM + WEIGHT_INDEX] == 0.0
    assert enc_zero[0, FEATURE_DIM + WEIGHT_INDEX] == 1.0
    assert not np.array_equal(enc_unknown, enc_zero)
    np.testing.assert_allclose(encode(x, known)[0, :FEATURE_DIM], x)


def test_winner_take_all_picks_largest_output_with_its_share() -> None:
    logits = torch.tensor([0.1, 2.0, -1.0, 1.5])
    winner, confidence, shares = winner_take_all(logits)
    assert winner == 1
    assert confidence == pytest.approx(float(torch.softmax(logits, 0)[1]))
    assert float(shares.sum()) == pytest.approx(1.0)
    assert 0.0 < confidence < 1.0


def test_add_address_keeps_old_units_and_grows_output() -> None:
    net = _net(addresses=3)
    before_w = net.output.weight.detach().clone()
    before_b = net.output.bias.detach().clone()
    hidden_before = [p.detach().clone() for p in net.hidden.parameters()]

    new = net.add_address(torch.Generator().manual_seed(7))

    assert new == 3
    assert net.n_addresses == 4
    assert torch.equal(net.output.weight[:3], before_w)
    assert torch.equal(net.output.bias[:3], before_b)
    for p, q in zip(net.hidden.parameters(), hidden_before, strict=True):
        assert torch.equal(p, q)


def test_init_is_seeded_and_leaves_global_rng_alone() -> None:
    state = torch.random.get_rng_state()
    a, b, c = _net(seed=1, addresses=2), _net(seed=1, addresses=2), _net(seed=2, addresses=2)
    assert torch.equal(torch.random.get_rng_state(), state)
    for (_, pa), (_, pb) in zip(a.state_dict().items(), b.state_dict().items(), strict=True):
        assert torch.equal(pa, pb)
    assert not torch.equal(a.output.weight, c.output.weight)


def test_empty_network_has_no_winner() -> None:
    winner, confidence, shares = _net().recall(np.zeros(FEATURE_DIM), np.ones(FEATURE_DIM))
    assert (winner, confidence, shares.size) == (-1, 0.0, 0)


def _train(seed: int) -> tuple[AssociativeNetwork, np.ndarray, np.ndarray, int]:
    rng = np.random.default_rng(3)
    x = rng.random((6, FEATURE_DIM)).astype(np.float32)
    k = np.ones_like(x, bool)
    net = _net(addresses=6)
    steps = train_replay(net, x, k, np.arange(6), 5, MemoryConfig(), np.random.default_rng(seed))
    return net, x, k, steps


def test_train_replay_recalls_every_exemplar_with_confidence() -> None:
    net, x, k, steps = _train(seed=0)
    cfg = MemoryConfig()
    assert cfg.train_steps <= steps <= cfg.max_train_steps
    shares = net.shares(x, k)
    np.testing.assert_array_equal(shares.argmax(axis=1), np.arange(6))
    assert shares[np.arange(6), np.arange(6)].min() >= cfg.recall_confidence


def test_train_replay_is_deterministic_for_a_seed() -> None:
    a, *_ = _train(seed=4)
    b, *_ = _train(seed=4)
    c, *_ = _train(seed=5)
    assert torch.equal(a.output.weight, b.output.weight)
    assert not torch.equal(a.output.weight, c.output.weight)


@pytest.mark.parametrize(("field", "value"), [
    ("hidden_sizes", ()),
    ("hidden_sizes", (0,)),
    ("learning_rate", 0.0),
    ("learning_rate", float("nan")),
    ("batch_size", 0),
    ("train_steps", 2.5),
    ("max_train_steps", 10),
    ("recall_confidence", 1.5),
    ("new_fraction", -0.1),
    ("train_noise_std", -1.0),
    ("unknown_feature_prob", 2.0),
    ("maskable_features", ("Z",)),
    ("acceptance_distance", 0.0),
    ("max_component_difference", -0.1),
    ("ambiguity_margin", -0.01),
    ("confidence_threshold", 1.1),
    ("max_exemplars_per_address", 0),
])
def test_config_rejects_bad_value_naming_field(field: str, value: object) -> None:
    with pytest.raises(ConfigError, match=field):
        MemoryConfig(**{field: value})


def test_config_round_trips_through_dict() -> None:
    cfg = MemoryConfig(hidden_sizes=(32, 16), acceptance_distance=0.05)
    assert MemoryConfig.from_dict(cfg.to_dict()) == cfg
    with pytest.raises(ConfigError, match="bogus"):
        MemoryConfig.from_dict({"bogus": 1})


def test_first_store_imports_nothing_new() -> None:
    """torch's first optimizer step imports torch._dynamo (>1 s): building a memory pays it,
    so the first store of a running graph does not stall on an import."""
    import subprocess
    import sys

    script = (
        "import sys, numpy as np\n"
        "from roger_memory.memory import AssociativeMemory\n"
        "m = AssociativeMemory(seed=0)\n"
        "before = set(sys.modules)\n"
        "m.store(np.full(11, 0.5, np.float32), np.ones(11, bool))\n"
        "print(sorted(n for n in set(sys.modules) - before if n.startswith('torch')))\n")
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         timeout=120, check=True).stdout.strip()
    assert out == "[]", out[:300]
