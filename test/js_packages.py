"""The npm packages of test/js (Foxglove's readers and WebSocket client), installed from its
package-lock.json by `make bootstrap` (npm ci); a test that needs them calls
``ensure_js_packages`` first, which runs npm ci when they are missing or older than the
lock. A failing npm fails the test (never a skip)."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

JS = Path(__file__).resolve().parent / "js"


def ensure_js_packages(needed_for: str) -> None:
    """npm ci in test/js unless its node_modules matches the lock; ``needed_for`` names
    what the packages are for in the failure message."""
    lock, installed = JS / "package-lock.json", JS / "node_modules" / ".package-lock.json"
    if installed.exists() and installed.stat().st_mtime >= lock.stat().st_mtime:
        return
    try:
        proc = subprocess.run(["npm", "ci", "--no-audit", "--no-fund"], cwd=JS,
                              capture_output=True, text=True, timeout=600)
    except FileNotFoundError:
        pytest.fail(f"npm is not installed: Node.js 20 with npm is needed for {needed_for} "
                    "(see README, Setup)")
    if proc.returncode != 0:
        pytest.fail(f"npm ci in {JS} failed:\n{proc.stdout[-2000:]}{proc.stderr[-2000:]}")
