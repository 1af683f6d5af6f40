"""``roger bench --quick``: bench.json has every contract key with sane values.

No timing thresholds: only that each ratio is a positive finite number, that the ratios
agree with the raw figures they are made of, and that the graph ran the same goals as the
in-process core loop. The quick mode starts the real graph twice (about 40 s).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from roger_bringup.bench import main_bench

CONTRACT = ("graph_vs_core", "cycle_vs_floor", "scaling_64_vs_4", "match_1000_vs_10",
            "stages", "cycles_per_s_128", "cycles_per_s_256")
STAGES = ("render", "physics", "servo_control", "log", "segment", "stereo_match",
          "features", "activation", "memory_matching", "policy", "transport")


@pytest.fixture(scope="module")
def bench(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict, dict, Path]:
    out = tmp_path_factory.mktemp("bench")
    # What an earlier bench left in the graph's folder must not be loaded (a memory of
    # learned objects made the graph skip stores: a flattering graph_vs_core).
    (out / "graph_128").mkdir()
    (out / "graph_128" / "memory.pt").write_bytes(b"an earlier run's memory")
    lines: list[str] = []
    result = main_bench(out, quick=True, log=lines.append)
    on_disk = json.loads((out / "bench.json").read_text())
    return result, on_disk, out


def test_every_key_is_written(bench: tuple[dict, dict, Path]) -> None:
    _, on_disk, _ = bench
    for key in CONTRACT:
        assert key in on_disk, key
    for key in CONTRACT[:4] + CONTRACT[5:]:
        assert isinstance(on_disk[key], float) and math.isfinite(on_disk[key]), key
        assert on_disk[key] > 0, key
    for stage in STAGES:
        assert isinstance(on_disk["stages"][stage], float), stage
        if stage != "transport":  # graph minus core: may be negative in a noisy quick run
            assert on_disk["stages"][stage] >= 0, stage


def test_ratios_are_made_of_the_raw_figures(bench: tuple[dict, dict, Path]) -> None:
    r, _, _ = bench
    assert r["graph_vs_core"] == pytest.approx(r["cycles_per_s_128"]
                                               / r["core_cycles_per_s_128"])
    assert r["cycle_vs_floor"] == pytest.approx(r["graph_ms_per_cycle"]
                                                / r["floor_ms_per_cycle"])
    assert r["match_1000_vs_10"] == pytest.approx(r["match_us_1000"] / r["match_us_10"])
    s = r["scaling"]
    assert r["scaling_64_vs_4"] == pytest.approx(s["ms_per_cycle_64"] / s["ms_per_cycle_4"])
    # The floor is part of the cycle, so a cycle cannot be cheaper than its floor.
    assert r["core_ms_per_cycle"] > r["floor_ms_per_cycle"] > 0
    assert r["stages"]["render"] + r["stages"]["physics"] == pytest.approx(
        r["floor_ms_per_cycle"], abs=2e-3)  # stages are rounded to 1 us


def test_graph_ran_the_same_cycles_as_the_core(bench: tuple[dict, dict, Path]) -> None:
    r, _, out = bench
    assert r["quick"] is True
    assert r["cycles"]["graph"] == r["cycles"]["core"] > 1
    assert r["graph_matches_core"] is True
    assert (out / "graph_128" / "cycles.csv").exists()
    assert r["cycles"]["scaling_64"] > 1 and r["cycles"]["scaling_4"] > 1


def test_rounds_pool_their_cycles_not_their_rates() -> None:
    from roger_bringup.bench import CoreRun, pool_core
    # Round 1: 2 steady cycles in 3 s (floor 1.5 s); round 2: 1 cycle in 4 s (floor 2 s).
    a = CoreRun(3, [0.0, 1.0, 3.0], [0.0, 0.5, 1.5], {"render": 1.0}, [], 10, 1.0)
    b = CoreRun(2, [10.0, 14.0], [5.0, 7.0], {"render": 3.0}, [], 10, 1.0)
    pooled = pool_core([a, b])
    assert pooled.seconds_per_cycle == pytest.approx(7.0 / 3)   # not the mean of 1.5 and 4
    assert pooled.floor_per_cycle == pytest.approx(3.5 / 3)
    assert pooled.stages["render"] == pytest.approx((1.0 * 2 + 3.0 * 1) / 3)
    assert pool_core([a]) is a
