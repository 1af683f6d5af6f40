"""Unit tests of the radial BP network with winner-take-all and of MemoryConfig."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from roger_common.errors import ConfigError
from roger_common.types import FEATURE_DIM, WEIGHT_INDEX
from roger_memory.config import MemoryConfig
from roger_memory.network import (
    SILENT,
    AssociativeNetwork,
    novel_offsets,
    student_t_noise,
    train_replay,
    winner_take_all,
)

pytestmark = pytest.mark.usefixtures("one_torch_thread")
CONFIG = MemoryConfig.for_mode("paper")  # these tests build paper-mode (11) looks


def _net(looks: np.ndarray, known: np.ndarray, addresses: list[int]) -> AssociativeNetwork:
    net = AssociativeNetwork(CONFIG.feature_scale, CONFIG.identify_distance,
                             CONFIG.min_common_features, CONFIG.feature_weight)
    for a in range(max(addresses) + 1):
        net.add_address()
    for x, k, a in zip(looks, known, addresses, strict=True):
        net.add_units(x[None], k[None], a)
    return net


def _weighted_mean(z2: np.ndarray, common: np.ndarray) -> float:
    w = np.asarray(CONFIG.feature_weight)
    return float((w * z2)[common].sum() / w[common].sum())


def test_unit_activation_is_the_weighted_mean_squared_z_over_common_known_features() -> None:
    rng = np.random.default_rng(0)
    looks = rng.random((3, FEATURE_DIM)).astype(np.float32)
    known = np.ones((3, FEATURE_DIM), bool)
    known[1, WEIGHT_INDEX] = False
    net = _net(looks, known, [0, 1, 1])
    q = rng.random(FEATURE_DIM).astype(np.float32)
    kq = np.ones(FEATURE_DIM, bool)
    kq[2] = False
    d2 = net.unit_distances(torch.from_numpy(q[None]),
                            torch.from_numpy(kq[None]))[0].detach().numpy()
    sigma = np.sqrt(2.0) * np.asarray(CONFIG.feature_scale)
    for j in (0, 2):
        common = known[j] & kq
        expected = _weighted_mean(((q - looks[j]) / sigma) ** 2, common)
        assert d2[j] == pytest.approx(expected, rel=1e-4)
    # A look never weighed is silent to a weighed query (it cannot vouch for a weight) ...
    assert d2[1] == SILENT
    per_address = net.address_distances(torch.from_numpy(d2[None]))[0].detach().numpy()
    np.testing.assert_allclose(per_address, [d2[0], d2[2]], rtol=1e-6)
    # ... and answers one whose weight is not measured either, over the common features.
    kq[WEIGHT_INDEX] = False
    d2 = net.unit_distances(torch.from_numpy(q[None]),
                            torch.from_numpy(kq[None]))[0].detach().numpy()
    expected = _weighted_mean(((q - looks[1]) / sigma) ** 2, known[1] & kq)
    assert d2[1] == pytest.approx(expected, rel=1e-4)


def test_unknown_is_left_out_never_taken_as_zero() -> None:
    x = np.full(FEATURE_DIM, 0.5, np.float32)
    x[WEIGHT_INDEX] = 0.7
    net = _net(x[None], np.ones((1, FEATURE_DIM), bool), [0])
    w_unknown = np.ones(FEATURE_DIM, bool)
    w_unknown[WEIGHT_INDEX] = False
    zero_w = x.copy()
    zero_w[WEIGHT_INDEX] = 0.0
    with torch.no_grad():
        unknown = net.unit_distances(torch.from_numpy(zero_w[None]),
                                     torch.from_numpy(w_unknown[None]))
        zero = net.unit_distances(torch.from_numpy(zero_w[None]),
                                  torch.from_numpy(np.ones((1, FEATURE_DIM), bool)))
    assert float(unknown) == pytest.approx(0.0, abs=1e-3)
    assert float(zero) > 100.0


def test_a_unit_with_too_few_common_features_is_silent() -> None:
    x = np.full((1, FEATURE_DIM), 0.5, np.float32)
    net = _net(x, np.ones((1, FEATURE_DIM), bool), [0])
    few = np.zeros(FEATURE_DIM, bool)
    few[:CONFIG.min_common_features - 1] = True
    with torch.no_grad():
        d2 = net.unit_distances(torch.from_numpy(x), torch.from_numpy(few[None]))
    assert float(d2) == SILENT
    winner, _, _, _ = net.recall(x[0], few)
    assert winner == 0  # the novel unit


def test_winner_take_all_picks_largest_output_with_its_share() -> None:
    logits = torch.tensor([0.1, 2.0, -1.0, 1.5])
    winner, confidence, shares = winner_take_all(logits)
    assert winner == 1
    assert confidence == pytest.approx(float(torch.softmax(logits, 0)[1]))
    assert float(shares.sum()) == pytest.approx(1.0)
    assert 0.0 < confidence < 1.0


def test_growing_keeps_the_old_units_and_outputs() -> None:
    rng = np.random.default_rng(1)
    looks = rng.random((3, FEATURE_DIM)).astype(np.float32)
    net = _net(looks, np.ones((3, FEATURE_DIM), bool), [0, 1, 2])
    with torch.no_grad():
        net.bias += torch.tensor([0.1, 0.2, 0.3])
    centres, bias = net.centres.detach().clone(), net.bias.detach().clone()
    assert net.add_address() == 3
    net.add_units(rng.random((2, FEATURE_DIM)), np.ones((2, FEATURE_DIM), bool), 3)
    assert (net.n_addresses, net.n_units) == (4, 5)
    assert torch.equal(net.centres[:3], centres)
    assert torch.equal(net.bias[:3], bias)
    assert net.unit_address.tolist() == [0, 1, 2, 3, 3]


def test_empty_network_answers_with_the_novel_unit() -> None:
    net = AssociativeNetwork(CONFIG.feature_scale, CONFIG.identify_distance, 6)
    winner, confidence, shares, d2 = net.recall(np.zeros(FEATURE_DIM), np.ones(FEATURE_DIM))
    assert (winner, confidence, shares.size, d2.size) == (0, 1.0, 1, 0)


def test_untrained_copy_has_the_shape_but_not_the_answers() -> None:
    rng = np.random.default_rng(2)
    looks = rng.random((4, FEATURE_DIM)).astype(np.float32)
    net = _net(looks, np.ones((4, FEATURE_DIM), bool), [0, 1, 2, 3])
    state = torch.random.get_rng_state()
    copy = net.untrained_copy(torch.Generator().manual_seed(0))
    assert torch.equal(torch.random.get_rng_state(), state)
    for (name, a), (_, b) in zip(net.state_dict().items(), copy.state_dict().items(),
                                 strict=True):
        assert a.shape == b.shape, name
    assert not torch.equal(net.centres, copy.centres)
    winners = [net.recall(x, np.ones(FEATURE_DIM, bool))[0] for x in looks]
    assert winners == [1, 2, 3, 4]


def _train(seed: int) -> tuple[AssociativeNetwork, np.ndarray, np.ndarray, int]:
    x = np.random.default_rng(3).random((6, FEATURE_DIM)).astype(np.float32)
    k = np.ones_like(x, bool)
    net = _net(x, k, list(range(6)))
    steps = train_replay(net, x, k, np.arange(6), 5, CONFIG, np.random.default_rng(seed))
    return net, x, k, steps


def test_train_replay_recalls_every_look_with_confidence() -> None:
    net, x, k, steps = _train(seed=0)
    assert CONFIG.train_steps <= steps <= CONFIG.max_train_steps
    shares = net.shares(x, k)
    np.testing.assert_array_equal(shares.argmax(axis=1), np.arange(1, 7))
    assert shares[np.arange(6), np.arange(1, 7)].min() >= CONFIG.recall_confidence
    # Training keeps the calibrated metric (the prior) while sharpening the outputs.
    np.testing.assert_allclose(net.scale, CONFIG.feature_scale, rtol=0.25)
    assert net.tau == pytest.approx(CONFIG.identify_distance, rel=0.25)


def test_train_replay_is_deterministic_for_a_seed() -> None:
    a, *_ = _train(seed=4)
    b, *_ = _train(seed=4)
    c, *_ = _train(seed=5)
    assert torch.equal(a.log_scale, b.log_scale) and torch.equal(a.centres, b.centres)
    assert not torch.equal(a.log_scale, c.log_scale)


def test_student_t_noise_has_a_heavier_tail_than_a_gaussian() -> None:
    rng = np.random.default_rng(6)
    t = student_t_noise(rng, (20000, FEATURE_DIM), 5.0)
    g = rng.standard_normal((20000, FEATURE_DIM))
    rms_t, rms_g = np.sqrt((t ** 2).mean(axis=1)), np.sqrt((g ** 2).mean(axis=1))
    assert np.median(rms_t) == pytest.approx(np.median(rms_g), rel=0.2)
    assert np.quantile(rms_t, 0.99) > 1.4 * np.quantile(rms_g, 0.99)


@pytest.mark.parametrize(("field", "value"), [
    ("feature_scale", (0.01,) * (FEATURE_DIM - 1)),
    ("feature_scale", (0.0,) * FEATURE_DIM),
    ("veto", (float("nan"),) * FEATURE_DIM),
    ("identify_distance", 0.0),
    ("noise_dof", -1.0),
    ("min_common_features", 0),
    ("min_common_features", FEATURE_DIM + 1),
    ("identify_share", 1.5),
    ("refine_looks", 0),
    ("learning_rate", 0.0),
    ("learning_rate", float("nan")),
    ("batch_size", 0),
    ("train_steps", 2.5),
    ("max_train_steps", 10),
    ("recall_confidence", 1.5),
    ("new_fraction", -0.1),
    ("novel_fraction", 1.0),
    ("novel_far", 0.5),
    ("prior_weight", -1.0),
    ("unknown_feature_prob", 2.0),
    ("feature_weight", (1.0,) * 10),
    ("feature_weight", (0.0,) * 11),
    ("feature_weight", (-1.0,) + (1.0,) * 10),
    ("maskable_features", ("Z",)),
])
def test_config_rejects_bad_value_naming_field(field: str, value: object) -> None:
    with pytest.raises(ConfigError, match=field):
        MemoryConfig.for_mode("paper", **{field: value})


def test_config_round_trips_through_dict() -> None:
    cfg = MemoryConfig.for_mode("paper", identify_distance=2.5, veto=(0.5,) * FEATURE_DIM)
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
        "from roger_memory.config import MemoryConfig\n"
        "m = AssociativeMemory(MemoryConfig.for_mode('paper'), seed=0)\n"
        "before = set(sys.modules)\n"
        "m.store(np.full(11, 0.5, np.float32), np.ones(11, bool))\n"
        "print(sorted(n for n in set(sys.modules) - before if n.startswith('torch')))\n")
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         timeout=120, check=True).stdout.strip()
    assert out == "[]", out[:300]


def test_the_z_cap_bounds_what_one_feature_adds_and_nothing_else() -> None:
    """MemoryConfig.z_cap (the extended mode's robust distance): a look that agrees with a
    unit in every feature but one, off by 20 scales there, lies within tau with the cap and
    far beyond it without; a look off by 1 scale everywhere lies where it did."""
    from roger_memory.calibration import rms_z
    scale = np.full(FEATURE_DIM, 0.01)
    weight = tuple([1.0] * FEATURE_DIM)
    stored = np.full((1, FEATURE_DIM), 0.5, np.float32)
    one_off = stored[0].copy()
    one_off[3] += 20 * np.sqrt(2.0) * 0.01
    everywhere = stored[0] + np.float32(np.sqrt(2.0) * 0.01)
    known = np.ones((1, FEATURE_DIM), bool)
    out = {}
    for cap in (0.0, 3.0):
        net = AssociativeNetwork(tuple(scale), 2.0, 6, weight, z_cap=cap)
        net.add_address()
        net.add_units(stored, known, 0)
        x = torch.from_numpy(np.stack([one_off, everywhere]))
        all_known = torch.from_numpy(np.ones((2, FEATURE_DIM), bool))
        out[cap] = net.unit_distances(x, all_known).detach()
        # The numpy distance of the memory and the calibration agrees with the network's.
        # The network expands |x - c|^2 in float32 (|x|^2 - 2 x.c + |c|^2, in units of the
        # scale: 2500 here), which loses about 2500 x 6e-8 absolutely; how much depends on
        # the CPU's summation order (1.7e-4 on one machine, under 1e-4 on another).
        d = rms_z(np.stack([one_off, everywhere]) - stored, np.ones((2, FEATURE_DIM), bool),
                  scale, np.asarray(weight), cap)
        np.testing.assert_allclose(out[cap][:, 0].numpy(), d ** 2, rtol=1e-4, atol=1e-3)
    assert out[0.0][0, 0] == pytest.approx(400 / FEATURE_DIM, rel=1e-3)
    assert out[3.0][0, 0] == pytest.approx(9 / FEATURE_DIM, rel=1e-3) and out[3.0][0, 0] < 4
    assert out[3.0][1, 0] == pytest.approx(out[0.0][1, 0].item(), rel=1e-3)


@pytest.mark.parametrize("mode", ["paper", "extended"])
def test_novel_samples_lie_beyond_tau_in_the_distance_the_network_uses(mode: str) -> None:
    """The replay's novel samples must be novel as the network measures them: with the
    extended mode's cap on each |z|, offsets drawn in the uncapped distance fell within
    tau (down to 0.7 tau) once capped, and offsets drawn only over the reachable range
    were three times as dense near tau as the paper mode's."""
    from roger_memory.calibration import rms_z

    cfg = MemoryConfig.for_mode(mode)
    rng = np.random.default_rng(3)
    dim = len(cfg.feature_scale)
    known = rng.random((4000, dim)) < 0.85
    known[:, :6] = True
    z = novel_offsets(rng, known, cfg)
    assert np.all(z[~known] == 0.0)
    sigma = np.sqrt(2.0) * np.asarray(cfg.feature_scale)
    d = rms_z(z * sigma, known, np.asarray(cfg.feature_scale),
              np.asarray(cfg.feature_weight), cfg.z_cap)
    tau = cfg.identify_distance
    near, far = cfg.novel_near * tau, cfg.novel_far * tau
    reach = far if cfg.z_cap <= 0 else min(far, cfg.z_cap)
    assert d.min() >= near * (1 - 1e-6)
    assert d.max() <= reach * (1 + 1e-6)
    # As dense per unit of distance as without a cap, wherever the distance can reach: the
    # share within near..r is (r - near) / (far - near) (uniform radius), so the boundary
    # the network learns near tau is the same in both modes.
    for r in np.linspace(near, reach, 6)[1:-1]:
        assert abs(np.mean(d <= r) - (r - near) / (far - near)) < 0.03, r
