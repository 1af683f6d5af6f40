"""The architecture's one rule: the science lives in plain Python, ROS is a thin skin.

Every core module must import with rclpy (and the message packages) made unimportable.
Node files (*_node.py), conversions.py and the orchestrator package are the ROS skin.
"""

from __future__ import annotations

import importlib
import subprocess
import sys
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"
CORE_PACKAGES = ("roger_common", "roger_sim", "roger_perception", "roger_memory",
                 "roger_attention")
SKIN = ("_node.py", "conversions.py")


def core_modules() -> list[str]:
    mods = []
    for pkg in CORE_PACKAGES:
        for f in sorted((SRC / pkg / pkg).glob("*.py")):
            if f.name.endswith(SKIN):
                continue
            mods.append(f"{pkg}.{f.stem}" if f.stem != "__init__" else pkg)
    return mods


def test_there_are_core_modules_to_check() -> None:
    mods = core_modules()
    for pkg in CORE_PACKAGES:
        assert pkg in mods
    assert len(mods) >= 20


@pytest.mark.parametrize("module", core_modules())
def test_core_module_imports_without_ros(module: str) -> None:
    blocked = ["rclpy", "std_msgs", "sensor_msgs", "geometry_msgs", "rosgraph_msgs",
               "builtin_interfaces", "rcl_interfaces", "roger_interfaces", "diagnostic_msgs"]
    code = ("import sys\n"
            + "".join(f"sys.modules[{m!r}] = None\n" for m in blocked)
            + f"import importlib; importlib.import_module({module!r})\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, f"{module} needs ROS to import:\n{proc.stderr[-2000:]}"


def test_the_check_catches_a_ros_import() -> None:
    # The check itself must be able to fail: a node module does import rclpy.
    code = "import sys; sys.modules['rclpy'] = None; import roger_memory.memory_node"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode != 0
    assert importlib.util.find_spec("roger_memory.memory_node") is not None
