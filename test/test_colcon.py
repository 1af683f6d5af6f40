"""src/ builds as a ROS 2 workspace with colcon (issue 36, item 6).

A copy of src/ is built by ``colcon build`` (colcon-core and colcon-ros, pinned in
requirements.txt) in a temporary workspace against the venv's ament, rosidl and message
packages, with only what README's "Building with colcon" asks for: the venv's bin first on
PATH and ``AMENT_PREFIX_PATH`` at the venv. Every package that has a package.xml under src/
must be built and installed (so a new package is covered without touching this test), and
the installed entry points must start from the install space, through its ``setup.sh``,
not from the venv's editable installs. The nodes' executables must be where ``ros2 run``
looks (``lib/<pkg>``, the ament_python layout of each node package's setup.cfg), ``roger``
on PATH (``bin``, as ros2cli's ``ros2``), and each node must answer ``--help`` from any
directory (the simulator's default world comes from ``share/roger_sim/worlds``). Building
roger_interfaces (the C, C++ and Python code of its messages) is most of the time: 75-130 s
on a busy 2-core machine.
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
HELP_TIMEOUT = 90  # seconds for a node's --help (an import of torch on a busy machine)


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
    # Beside src/ as in the repository: roger_sim's setup.py installs ../../worlds.
    shutil.copytree(REPO / "worlds", ws / "worlds")
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
# setup.sh) and says where each one's module came from, and which package and module it
# belongs to.
ENTRY_POINTS = """
import importlib.metadata as md, json, sys
found = {}
for ep in md.entry_points(group="console_scripts"):
    if ep.dist.name.replace("-", "_").startswith("roger_"):
        assert callable(ep.load()), ep
        found[ep.name] = [sys.modules[ep.module].__file__, ep.dist.name.replace("-", "_"),
                          ep.module]
import roger_interfaces.msg
found["roger_interfaces.msg"] = [roger_interfaces.msg.__file__, "roger_interfaces", ""]
print(json.dumps(found))
"""

# What `ros2 run PKG EXE ARGS` does (ros2run, ros2pkg.api.get_executable_path), for a shell
# without a ROS install's ros2 CLI: the package's prefix from the ament index, then
# PREFIX/lib/PKG/EXE, run in place of this interpreter.
ROS2_RUN = """
import os, sys
from ament_index_python.packages import get_package_prefix
package, executable = sys.argv[1:3]
path = os.path.join(get_package_prefix(package), "lib", package, executable)
os.execv(path, [path, *sys.argv[3:]])
"""


def in_install_space(workspace: Path, command: str,
                     cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    """Run a shell command after sourcing the install space's setup.sh."""
    script = f'. "{workspace}/install/setup.sh" && {command}'
    return subprocess.run(["sh", "-c", script], cwd=cwd or workspace, env=user_environment(),
                          capture_output=True, text=True, timeout=120)


def ros2_run(workspace: Path, cwd: Path, package: str, *args: str) -> tuple[int, str, str]:
    """(status, stdout, stderr) of ``ros2 run PACKAGE ARGS`` from the install space, in
    ``cwd``. A node that does not stop by itself within HELP_TIMEOUT gets SIGINT (a clean
    ROS shutdown: no Fast DDS file left behind) and the test fails."""
    script = (f'. "{workspace}/install/setup.sh" && exec "{sys.executable}" -c \'{ROS2_RUN}\' '
              + " ".join([package, *args]))
    proc = subprocess.Popen(["sh", "-c", script], cwd=cwd, env=user_environment(),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        out, err = proc.communicate(timeout=HELP_TIMEOUT)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGINT)
        try:
            out, err = proc.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            out, err = proc.communicate()
        pytest.fail(f"ros2 run {package} {' '.join(args)} still ran after {HELP_TIMEOUT} s "
                    f"(stopped with SIGINT):\n{tail(out)}\n{tail(err)}")
    return proc.returncode, out, err


def installed_scripts(workspace: Path) -> dict[str, list[str]]:
    """Console script -> [module file, package, module], loaded from the install space."""
    loaded = in_install_space(workspace, f'"{sys.executable}" -c \'{ENTRY_POINTS}\'')
    assert loaded.returncode == 0, loaded.stderr
    scripts: dict[str, list[str]] = json.loads(loaded.stdout.splitlines()[-1])
    return scripts


def node_executables(scripts: dict[str, list[str]]) -> dict[str, str]:
    """Executable -> package, for the console scripts that run a ROS node (``*_node``)."""
    return {name: pkg for name, (_, pkg, module) in scripts.items()
            if module.endswith("_node")}


def test_installed_entry_points_start_from_the_install_space(workspace: Path) -> None:
    install = workspace / "install"
    scripts = {p.name for p in install.glob("*/bin/*")} | {
        p.name for pkg in install.iterdir() for p in (pkg / "lib" / pkg.name).glob("*")}
    assert {"roger", "roger-sim"} <= scripts, f"installed scripts: {sorted(scripts)}"

    modules = installed_scripts(workspace)
    assert set(modules) - {"roger_interfaces.msg"} == scripts
    outside = {k: v for k, (v, _, _) in modules.items() if not Path(v).is_relative_to(install)}
    assert not outside, f"not loaded from the install space: {outside}"

    # Each node's executable where `ros2 run` looks, lib/<pkg>; `roger` is a command, on PATH.
    nodes = node_executables(modules)
    assert {"roger-sim", "roger-perception", "roger-memory", "roger-attention"} <= set(nodes)
    misplaced = {exe: pkg for exe, pkg in nodes.items()
                 if not (install / pkg / "lib" / pkg / exe).is_file()}
    assert not misplaced, f"not in install/<pkg>/lib/<pkg> (setup.cfg): {misplaced}"
    assert not [p for p in install.glob("*/bin/*") if p.name in nodes]

    roger = in_install_space(workspace, "command -v roger && roger --help")
    assert roger.returncode == 0, roger.stderr
    where, usage = roger.stdout.split("\n", 1)
    assert Path(where) == install / "roger_bringup" / "bin" / "roger"
    assert usage.startswith("usage: roger"), roger.stdout
    assert "run" in usage and "demo" in usage


def test_every_node_prints_its_usage_from_anywhere(workspace: Path, tmp_path: Path) -> None:
    # From an empty folder: no worlds/, no parameters file, nothing of the repository.
    for exe, pkg in sorted(node_executables(installed_scripts(workspace)).items()):
        status, out, err = ros2_run(workspace, tmp_path, pkg, exe, "--help")
        assert status == 0, f"{exe} --help: exit {status}\n{tail(out)}\n{tail(err)}"
        assert f"usage: {exe}" in out, f"{exe} --help printed no usage:\n{out}\n{err}"


def test_the_simulator_finds_its_default_world_in_the_install_space(workspace: Path,
                                                                    tmp_path: Path) -> None:
    code = ("from roger_sim.config import SimNodeConfig; "
            "from roger_sim.sim_node import resolve_world; "
            "print(resolve_world(SimNodeConfig().world))")
    found = in_install_space(workspace, f'"{sys.executable}" -c "{code}"', cwd=tmp_path)
    assert found.returncode == 0, found.stderr
    shipped = workspace / "install" / "roger_sim" / "share" / "roger_sim" / "worlds"
    assert Path(found.stdout.strip()) == shipped / "table1.yaml"
    assert sorted(p.name for p in shipped.glob("*.yaml")) == sorted(
        p.name for p in (REPO / "worlds").glob("*.yaml"))
