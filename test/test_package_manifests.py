"""Each package.xml declares what its package imports, so that the packages build and run
with colcon and rosdep in a ROS 2 workspace (issue 14, item 7).

Imports are read from the source with ``ast`` (top-level names of every ``import``);
standard-library modules need no declaration, the other packages of this repository and
ROS packages are declared by name, Python libraries by their rosdep key.
"""

from __future__ import annotations

import ast
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"
#: Python modules -> rosdep keys (``-pip`` where rosdep only knows the PyPI package).
ROSDEP_KEYS: dict[str, str] = {
    "numpy": "python3-numpy", "cv2": "python3-opencv", "yaml": "python3-yaml",
    "torch": "python3-torch", "matplotlib": "python3-matplotlib", "PIL": "python3-pil",
    "pybullet": "python3-pybullet-pip", "gymnasium": "python3-gymnasium-pip",
    "mcap": "python3-mcap-pip", "rich": "python3-rich", "ray": "python3-ray-pip",
    "foxglove": "python3-foxglove-sdk-pip"}
#: Imported by name at run time (importlib), so invisible to ``ast``.
DYNAMIC: dict[str, set[str]] = {
    "roger_bringup": {"rosgraph_msgs", "sensor_msgs", "roger_interfaces", "std_msgs", "tf2_msgs",
                      "visualization_msgs"}}
PACKAGES = sorted(p.name for p in SRC.iterdir() if (p / "setup.py").exists())


def imported(package: str) -> set[str]:
    """Top-level names the package's modules import (its own and the stdlib's left out)."""
    names: set[str] = set()
    for path in (SRC / package / package).rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                names |= {a.name.split(".")[0] for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names.add(node.module.split(".")[0])
    return names - set(sys.stdlib_module_names) - {"__future__", package}


def declared(package: str) -> set[str]:
    """The run-time dependencies of a package.xml (depend and exec_depend)."""
    root = ET.parse(SRC / package / "package.xml").getroot()
    assert root.findtext("name") == package
    return {e.text.strip() for tag in ("depend", "exec_depend") for e in root.iter(tag)
            if e.text}


def test_every_python_package_has_a_manifest() -> None:
    assert {"roger_common", "roger_experiments", "roger_bringup"} <= set(PACKAGES)


@pytest.mark.parametrize("package", PACKAGES)
def test_package_xml_declares_every_import(package: str) -> None:
    needed = {ROSDEP_KEYS.get(n, n) for n in imported(package) | DYNAMIC.get(package, set())}
    unknown = {n for n in needed if not n.startswith(("roger_", "python3-"))
               and not n.endswith(("_msgs", "_interfaces")) and n != "rclpy"}
    assert not unknown, f"{package}: add a rosdep key for {sorted(unknown)} to ROSDEP_KEYS"
    missing = needed - declared(package)
    assert not missing, f"src/{package}/package.xml lacks <exec_depend> {sorted(missing)}"


@pytest.mark.parametrize("package", PACKAGES)
def test_package_xml_declares_no_workspace_package_it_does_not_use(package: str) -> None:
    # The workspace order colcon derives from these must follow the import layers.
    used = {n for n in imported(package) | DYNAMIC.get(package, set()) if n.startswith("roger_")}
    stale = {d for d in declared(package) if d.startswith("roger_")} - used
    assert not stale, f"src/{package}/package.xml declares {sorted(stale)} but never imports it"
