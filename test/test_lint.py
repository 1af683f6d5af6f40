"""The project's static checks hold: ruff (ruff.toml) over src, test and bench, the import
contracts of the architecture (.importlinter) and mypy over src (mypy.ini).

The same three run in ``make lint``.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent


def _run(*cmd: str, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(BIN / cmd[0]), *cmd[1:]], cwd=REPO, capture_output=True,
                          text=True, timeout=timeout)


def test_ruff_is_clean() -> None:
    proc = _run("ruff", "check", "src", "test", "bench")
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-1000:]


def test_import_contracts_hold() -> None:
    # Layers (launcher > experiments > science packages > roger_common), the science
    # packages independent of one another, the experiments free of ROS, and the experiment
    # modules in layers (results < plots < train < runners < table2 < compare, ray_runner
    # < sweep).
    proc = _run("lint-imports", "--no-cache")
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-1000:]
    assert "4 kept, 0 broken" in proc.stdout, proc.stdout[-2000:]


def test_mypy_is_clean() -> None:
    proc = _run("mypy", "--cache-dir", "/dev/null")
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-1000:]
