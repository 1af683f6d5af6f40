"""src/ builds as a ROS 2 workspace with colcon (issue 36, item 6).

A copy of src/ is built by ``colcon build`` (colcon-core and colcon-ros, pinned in
requirements.txt) in a temporary workspace against the venv's ament, rosidl and message
packages, with only what README's "Building with colcon" asks for: the venv's bin first on
PATH and ``AMENT_PREFIX_PATH`` at the venv. Every package that has a package.xml under src/
must be built and installed (so a new package is covered without touching this test), and
the installed entry points must start from the install space, through its ``setup.sh``,
not from the venv's editable installs. Building roger_interfaces (the C, C++ and Python
code of its messages) is most of the time: 75-130 s on a busy 2-core machine.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SRC = REPO / "src"
VENV = Path(sys.prefix)
VENV_BIN = Path(sys.executable).parent
BUILD_TIMEOUT = 600  # seconds; the build takes 75-130 s on 2 busy cores


def source_packages() -> dict[str, Path]:
    """Package name -> folder, for every package.xml under src/ that colcon would see."""
    packages = {}
    for xml in sorted(SRC.rglob("package.xml")):
        folder = xml.parent
        if any((d / "COLCON_IGNORE").exists() for d in [folder, *folder.parents]
               if d.is_relative_to(SRC)):
            continue
        name = ET.parse(xml).getroot().findtext("name")
        assert name, f"{xml.relative_to(REPO)} has no <name>"
        packages[name.strip()] = folder
    return packages


def user_environment() -> dict[str, str]:
    """A shell as README's recipe leaves it: venv activated, AMENT_PREFIX_PATH at the venv,
    nothing of another ROS workspace, and the ROS wheels' own bootstrap not yet done."""
    drop = ("AMENT_", "COLCON_", "CMAKE_", "ROS_DISTRO", "_ROS_WHEELS_")
    env = {k: v for k, v in os.environ.items()
           if not k.startswith(drop) and k not in {"PYTHONPATH", "LD_LIBRARY_PATH"}}
    env["PATH"] = os.pathsep.join([str(VENV_BIN), env.get("PATH", "")])
    env["VIRTUAL_ENV"] = str(VENV)
    env["AMENT_PREFIX_PATH"] = str(VENV)
    return env


def tail(text: str, lines: int = 60) -> str:
    return "\n".join(text.splitlines()[-lines:])


@pytest.fixture(scope="module")
def workspace(tmp_path_factory) -> Path:
    """A workspace with a copy of src/, built and installed by colcon; its root."""
    colcon = VENV_BIN / "colcon"
    if not colcon.exists():
        pytest.fail(f"{colcon} is missing: make bootstrap installs colcon (requirements.txt)")
    ws = tmp_path_factory.mktemp("colcon_ws")
    shutil.copytree(SRC, ws / "src", symlinks=True,
                    ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
    env = user_environment()
    env["COLCON_HOME"] = str(ws / "colcon_home")  # no user defaults or mixins
    # Its own session, so that a timeout also ends the cmake, make and compilers under it.
    colcon_build = subprocess.Popen(
        [str(colcon), "--log-base", str(ws / "log"), "build",
         "--base-paths", str(ws / "src"), "--build-base", str(ws / "build"),
         "--install-base", str(ws / "install")],
        cwd=ws, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        start_new_session=True)
    try:
        output, _ = colcon_build.communicate(timeout=BUILD_TIMEOUT)
    except subprocess.TimeoutExpired:
        os.killpg(colcon_build.pid, signal.SIGKILL)
        output, _ = colcon_build.communicate()
        pytest.fail(f"colcon build ran over {BUILD_TIMEOUT} s:\n{tail(output)}")
    (ws / "colcon_output.txt").write_text(output)
    assert colcon_build.returncode == 0, (
        f"colcon build failed (exit {colcon_build.returncode}); the end of its output:\n"
        f"{tail(output)}")
    return ws


def test_every_package_under_src_builds_and_installs(workspace: Path) -> None:
    expected = source_packages()
    assert {"roger_interfaces", "roger_common", "roger_bringup"} <= set(expected)
    output = (workspace / "colcon_output.txt").read_text()
    finished = {line.split()[2] for line in output.splitlines()
                if line.startswith("Finished <<< ")}
    assert finished == set(expected), (
        f"colcon finished {sorted(finished)}, src/ has {sorted(expected)}")
    install = workspace / "install"
    for name in expected:
        share = install / name / "share"
        assert (share / name / "package.xml").is_file(), f"{name}: no share/{name}/package.xml"
        marker = share / "ament_index" / "resource_index" / "packages" / name
        assert marker.is_file(), f"{name}: not registered in the ament index ({marker})"
    # The messages' Python type support (the extension modules rclpy loads).
    python = f"python{sys.version_info[0]}.{sys.version_info[1]}"
    msg = install / "roger_interfaces" / "lib" / python / "site-packages" / "roger_interfaces"
    assert list(msg.glob("roger_interfaces_s__rosidl_typesupport_c*.so")), (
        "roger_interfaces: no Python type support installed")


# Imports every console script of the install space (a fresh interpreter, through
# setup.sh) and says where each one's module came from.
ENTRY_POINTS = """
import importlib.metadata as md, json, sys
found = {}
for ep in md.entry_points(group="console_scripts"):
    if ep.dist.name.replace("-", "_").startswith("roger_"):
        assert callable(ep.load()), ep
        found[ep.name] = sys.modules[ep.module].__file__
import roger_interfaces.msg
found["roger_interfaces.msg"] = roger_interfaces.msg.__file__
print(json.dumps(found))
"""


def in_install_space(workspace: Path, command: str) -> subprocess.CompletedProcess[str]:
    """Run a shell command after sourcing the install space's setup.sh."""
    script = f'. "{workspace}/install/setup.sh" && {command}'
    return subprocess.run(["sh", "-c", script], cwd=workspace, env=user_environment(),
                          capture_output=True, text=True, timeout=120)


def test_installed_entry_points_start_from_the_install_space(workspace: Path) -> None:
    install = workspace / "install"
    scripts = {p.name for p in install.glob("*/bin/*")}
    assert {"roger", "roger-sim"} <= scripts, f"installed scripts: {sorted(scripts)}"

    loaded = in_install_space(workspace, f'"{sys.executable}" -c \'{ENTRY_POINTS}\'')
    assert loaded.returncode == 0, loaded.stderr
    modules = json.loads(loaded.stdout.splitlines()[-1])
    assert set(modules) - {"roger_interfaces.msg"} == scripts
    outside = {k: v for k, v in modules.items() if not Path(v).is_relative_to(install)}
    assert not outside, f"not loaded from the install space: {outside}"

    roger = in_install_space(workspace, "command -v roger && roger --help")
    assert roger.returncode == 0, roger.stderr
    where, usage = roger.stdout.split("\n", 1)
    assert Path(where) == install / "roger_bringup" / "bin" / "roger"
    assert usage.startswith("usage: roger"), roger.stdout
    assert "run" in usage and "demo" in usage
