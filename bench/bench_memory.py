"""Benchmark of the associative memory: a match and a store against 10, 100, 1,000 objects.

Not a test. Run from the repository root::

    PYTHONPATH=src/roger_common:src/roger_memory python bench/bench_memory.py

Each memory is preloaded with ``store_many`` (one retraining), then a match (median of
``--matches`` queries of stored objects, each moved by the calibrated repeat noise of the
robot's looks) and a store of a new object (median of ``--stores`` consecutive stores,
each with its full replay retraining) are timed. Prints a table, then
``match_1000_vs_10`` (target <= 3) and ``store_1000_vs_10``.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
import torch

from roger_common.types import MatchOutcome, feature_dim
from roger_memory.config import MemoryConfig
from roger_memory.memory import AssociativeMemory
from roger_memory.network import student_t_noise


def bench_size(n: int, matches: int, stores: int, seed: int) -> dict[str, float]:
    """Time preload, match and store for a memory of ``n`` objects."""
    rng = np.random.default_rng(seed)
    config = MemoryConfig()  # the default feature mode's
    dim = feature_dim(config.features)
    patterns = rng.random((n + stores, dim)).astype(np.float32)
    known = np.ones((n + stores, dim), bool)
    sigma = np.sqrt(2.0) * np.asarray(config.feature_scale)
    memory = AssociativeMemory(config, seed=seed)
    t0 = time.perf_counter()
    memory.store_many(patterns[:n], known[:n])
    preload_s = time.perf_counter() - t0
    preload_steps = memory.last_train_steps

    match_times, identified = [], 0
    for i in rng.integers(0, n, matches):
        noise = student_t_noise(rng, (1, dim), config.noise_dof)[0] * sigma
        q = np.clip(patterns[i] + noise, 0.0, 1.0)
        t0 = time.perf_counter()
        result = memory.match(q, known[i])
        match_times.append(time.perf_counter() - t0)
        identified += result.outcome == MatchOutcome.IDENTIFIED and result.address == i

    store_times, store_steps = [], []
    for j in range(n, n + stores):
        t0 = time.perf_counter()
        memory.store(patterns[j], known[j])
        store_times.append(time.perf_counter() - t0)
        store_steps.append(memory.last_train_steps)
    recalled = sum(memory.match(patterns[j], known[j]).address == j for j in range(n + stores))
    return {
        "n": n,
        "preload_s": preload_s,
        "preload_steps": preload_steps,
        "match_us": statistics.median(match_times) * 1e6,
        "identified": identified / matches,
        "store_ms": statistics.median(store_times) * 1e3,
        "store_max_ms": max(store_times) * 1e3,
        "store_steps": statistics.median(store_steps),
        "recalled_after": recalled / (n + stores),
    }


def main() -> None:
    """Parse arguments, run every size, print the table and the ratios."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[10, 100, 1000])
    parser.add_argument("--matches", type=int, default=300)
    parser.add_argument("--stores", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=1, help="torch.set_num_threads")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    # Warm torch up so the first size does not pay for lazy initialisation.
    bench_size(3, 5, 1, args.seed)

    rows = [bench_size(n, args.matches, args.stores, args.seed) for n in args.sizes]
    print(f"torch {torch.__version__}, {torch.get_num_threads()} thread(s), "
          f"config {MemoryConfig()}")
    header = ("objects", "preload s", "steps", "match us", "ident", "store ms", "max ms",
              "steps", "recall")
    print(" | ".join(f"{h:>9}" for h in header))
    for r in rows:
        print(" | ".join([
            f"{r['n']:>9d}", f"{r['preload_s']:>9.2f}", f"{r['preload_steps']:>9.0f}",
            f"{r['match_us']:>9.1f}", f"{r['identified']:>9.3f}", f"{r['store_ms']:>9.1f}",
            f"{r['store_max_ms']:>9.1f}", f"{r['store_steps']:>9.0f}",
            f"{r['recalled_after']:>9.3f}"]))
    by_n = {r["n"]: r for r in rows}
    if 10 in by_n and 1000 in by_n:
        print(f"match_1000_vs_10 = {by_n[1000]['match_us'] / by_n[10]['match_us']:.2f}")
        print(f"store_1000_vs_10 = {by_n[1000]['store_ms'] / by_n[10]['store_ms']:.2f}")


if __name__ == "__main__":
    main()
