"""The bad-input fuzz tests with a large budget (``make test`` runs them small).

Not a test. Run from the repository root::

    .venv/bin/python bench/fuzz.py                 # 2,000 cases per fuzz test, derandomized
    .venv/bin/python bench/fuzz.py --examples 20000 --seed 7   # random cases from seed 7

It runs ``test/test_fuzz_worlds.py`` and ``test/test_fuzz_messages.py`` through pytest with
``ROGER_FUZZ_EXAMPLES`` (and ``ROGER_FUZZ_SEED``) set (test/fuzz_settings.py) and prints
Hypothesis's statistics: the cases tried per test, and any failing input, shrunk.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--examples", type=int, default=2000, help="cases per fuzz test")
    parser.add_argument("--seed", type=int, default=None,
                        help="draw the cases at random from this seed (default: derandomized)")
    parser.add_argument("-k", default="", help="pytest -k expression (default: every test)")
    args = parser.parse_args()
    env = dict(os.environ, ROGER_FUZZ_EXAMPLES=str(args.examples))
    if args.seed is not None:
        env["ROGER_FUZZ_SEED"] = str(args.seed)
    cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
           "--hypothesis-show-statistics", "test/test_fuzz_worlds.py",
           "test/test_fuzz_messages.py"]
    if args.k:
        cmd += ["-k", args.k]
    return subprocess.run(cmd, cwd=REPO, env=env, check=False).returncode


if __name__ == "__main__":
    sys.exit(main())
