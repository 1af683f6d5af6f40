"""Starts the Roger graph as one OS process per node, watches it, and stops it cleanly.

``launch`` is not available from PyPI, so this is a plain Python orchestrator: it sets the
network hygiene (localhost discovery, a domain id per run, logs under the run's folder),
starts the four nodes, waits until each is visible on the graph (no fixed sleeps), records
the run through its own monitor node, and ends every child on completion, Ctrl-C or SIGTERM.
A child that dies mid-run (even by SIGKILL), or that stops answering (no heartbeat,
roger_common.liveness), is reported, what it left in /dev/shm is removed, and it is started
again; it resumes from the run's state folder (``ROGER_STATE_DIR``, docs/reliability.md).
"""

from __future__ import annotations

import ctypes
import os
import random
import re
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from roger_common.dds import (
    PROFILE_ENV,
    PROFILE_FILE,
    RESTART_PARTICIPANT_IDS,
    apply_dds_defaults,
    profile_with_participant_id,
    user_unicast_port,
)

#: Environment variable naming the folder where nodes keep what they need to resume.
STATE_DIR_ENV = "ROGER_STATE_DIR"

#: Node processes of the graph: (name, module).
NODES: tuple[tuple[str, str], ...] = (
    ("sim", "roger_sim.sim_node"),
    ("perception", "roger_perception.perception_node"),
    ("memory", "roger_memory.memory_node"),
    ("attention", "roger_attention.attention_node"),
)


def pick_domain_id() -> int:
    """A domain id for this run: ROS_DOMAIN_ID if the user set one, else a random one that
    no graph on this machine uses now (``domains_in_use``; any, if all are).

    Fast DDS on Linux accepts 0-101 (and 215-232) without port clashes; 0 is left to a
    user's default graph. A random draw alone once put a chaos run and another user's
    ``roger run`` on one domain: each recorded the other's cycles (docs/reliability.md).
    """
    env = os.environ.get("ROS_DOMAIN_ID")
    if env:
        return int(env)
    taken = domains_in_use()
    free = [d for d in range(1, 102) if d not in taken] or list(range(1, 102))
    return random.SystemRandom().choice(free)


def domains_in_use() -> set[int]:
    """Domains whose Fast DDS port files (``fastrtps_port<N>``, N = 7400 + 250 * domain +
    offset) are in /dev/shm now: a graph runs on them, or a killed one left them."""
    out = set()
    for name, _ in shm_files():
        m = re.fullmatch(r"(?:sem\.)?fastrtps_port(\d+)(?:_el|_mutex)?", name)
        if m is not None and int(m[1]) >= 7400:
            out.add((int(m[1]) - 7400) // 250)
    return out


def ros_environment(out_dir: Path, domain_id: int, base: dict[str, str] | None = None
                    ) -> dict[str, str]:
    """The environment of every process of a run.

    Localhost-only discovery is the default (traffic on these machines may only go to
    loopback); a user who exported ROS_AUTOMATIC_DISCOVERY_RANGE keeps theirs. The nodes'
    resume state goes to ``out_dir/state``.
    """
    env = dict(os.environ if base is None else base)
    env["ROS_DOMAIN_ID"] = str(domain_id)
    env[STATE_DIR_ENV] = str(out_dir / "state")
    apply_dds_defaults(env)  # LOCALHOST discovery, the shared-memory profile
    env["ROS_LOG_DIR"] = str(out_dir / "ros_logs")
    env.setdefault("PYTHONUNBUFFERED", "1")
    # Each node is single-threaded by design; one torch/BLAS thread each keeps the four
    # processes from fighting over two cores.
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        env.setdefault(var, "1")
    return env


def _die_with_parent() -> None:
    """Child side of Popen: get SIGTERM if the orchestrator dies, so no node is orphaned."""
    try:
        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except OSError:
        pass


def shm_files() -> set[tuple[str, int]]:
    """Fast DDS shared-memory files in /dev/shm, each as (name, inode).

    The inode tells a file made again under an old name from the old one: Fast DDS takes
    over the port of a killed participant (of this graph or another) by recreating its
    files, so a name that was there before the run may still be this run's leftover.
    """
    out = set()
    try:
        for entry in os.scandir("/dev/shm"):
            if "fastrtps" in entry.name or "fastdds" in entry.name:
                try:
                    out.add((entry.name, entry.inode()))
                except OSError:
                    continue
    except FileNotFoundError:
        pass
    return out


def shm_group(name: str) -> str:
    """The port or segment a Fast DDS file belongs to: ``sem.fastrtps_port7411_mutex`` and
    ``fastrtps_port7411_el`` belong to ``fastrtps_port7411``."""
    base = name[4:] if name.startswith("sem.") else name
    for suffix in ("_mutex", "_el"):
        if base.endswith(suffix):
            base = base[:-len(suffix)]
    return base


def shm_holders(ignore: list[int] | tuple[int, ...] = ()) -> dict[str, set[int]]:
    """Files in /dev/shm by the live processes (other than ``ignore``) that have them open
    or mapped."""
    held: dict[str, set[int]] = {}
    skip = {str(p) for p in ignore}
    for pid_dir in Path("/proc").iterdir():
        if not pid_dir.name.isdigit() or pid_dir.name in skip:
            continue
        pid = int(pid_dir.name)
        names = []
        # One descriptor closing while it is listed (the listing's own, in this process)
        # must not hide the process's other holds.
        try:
            fds = list((pid_dir / "fd").iterdir())
        except OSError:
            fds = []
        for fd in fds:
            try:
                target = os.readlink(fd)
            except OSError:
                continue
            if target.startswith("/dev/shm/"):
                names.append(target[len("/dev/shm/"):])
        try:
            maps = (pid_dir / "maps").read_text()
        except OSError:
            maps = ""
        for line in maps.splitlines():
            if "/dev/shm/" in line:
                names.append(line.split("/dev/shm/", 1)[1].strip())
        for name in names:
            held.setdefault(name, set()).add(pid)
    return held


def held_shm_files(ignore: list[int] | tuple[int, ...] = ()) -> set[str]:
    """Files in /dev/shm that a live process (other than ``ignore``) has open or mapped."""
    return set(shm_holders(ignore))


def clean_shm(before: set[tuple[str, int]], pids: list[int]) -> list[str]:
    """Remove Fast DDS files left in /dev/shm by processes that were killed.

    Only files that appeared during the run (by name and inode) are removed, and only
    when no live process holds any file of their port or segment: a port's mutex file is
    never held, not even while its port is in use, so a concurrent graph keeps its own.

    Args:
        before: ``shm_files()`` before the run started (never removed).
        pids: Processes whose holds do not count: this process once its ROS context is
            destroyed (Fast DDS keeps a discovery port file mapped until exit, and nobody
            removes it after a peer was killed).
    """
    held = {shm_group(n) for n in held_shm_files(ignore=pids)}
    removed = []
    for name, _ in sorted(shm_files() - before):
        if shm_group(name) in held:
            continue
        try:
            os.unlink(f"/dev/shm/{name}")
            removed.append(name)
        except OSError:
            pass
    return removed


@dataclass
class Child:
    """One node process."""

    name: str
    module: str
    args: list[str]
    log_path: Path
    proc: subprocess.Popen[bytes] | None = None
    restarts: int = 0
    #: time.monotonic() of the last start.
    started_at: float = 0.0
    #: Fast DDS participant id given to the running process (None: Fast DDS's own choice).
    participant_id: int | None = None

    def start(self, env: dict[str, str]) -> None:
        """Start (or restart) the process, appending to its log."""
        self.started_at = time.monotonic()
        log = open(self.log_path, "ab")
        try:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", self.module, *self.args], env=env, stdout=log,
                stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, start_new_session=True,
                preexec_fn=_die_with_parent)
        finally:
            log.close()

    def exit_reason(self) -> str:
        """How the process ended, in words ("exit 1", "killed by SIGKILL")."""
        code = self.proc.returncode if self.proc is not None else None
        if code is not None and code < 0:
            try:
                return f"killed by {signal.Signals(-code).name}"
            except ValueError:
                return f"killed by signal {-code}"
        return f"exit {code}"

    def alive(self) -> bool:
        """True while the process runs."""
        return self.proc is not None and self.proc.poll() is None

    def log_tail(self, lines: int = 5) -> str:
        """The last lines of the node's log, for error messages."""
        try:
            text = self.log_path.read_text(errors="replace").strip().splitlines()
        except OSError:
            return ""
        return "\n".join(text[-lines:])


@dataclass
class Graph:
    """The node processes of one run."""

    out_dir: Path
    env: dict[str, str]
    node_args: dict[str, list[str]]
    children: list[Child] = field(default_factory=list)
    shm_before: set[tuple[str, int]] | None = None
    external: tuple[str, ...] = ()
    deaths: list[dict[str, Any]] = field(default_factory=list)
    #: Participant ids already given to restarted nodes.
    participant_ids: list[int] = field(default_factory=list)
    #: time.monotonic() at which each id of ``participant_ids`` was last given up (its
    #: process died); ids in use are absent.
    id_freed_at: dict[int, float] = field(default_factory=dict)

    def start(self) -> None:
        """Start every node process (except the ``external`` ones, started elsewhere)."""
        logs = self.out_dir / "logs"
        logs.mkdir(parents=True, exist_ok=True)
        if self.shm_before is None:
            self.shm_before = shm_files()
        for name, module in NODES:
            if name in self.external:
                continue
            args = ["--ros-args", "-p", "use_sim_time:=true", *self.node_args.get(name, [])]
            child = Child(name, module, args, logs / f"{name}.log")
            child.start(self.env)
            self.children.append(child)

    def dead(self) -> list[Child]:
        """Children that have exited."""
        return [c for c in self.children if not c.alive()]

    def restart(self, child: Child, reason: str | None = None) -> list[str]:
        """Reap a dead child (or kill a hung one), remove the /dev/shm files nobody needs any
        more, start it again.

        Args:
            child: The child to restart.
            reason: Why a child that is still running must go (say "unresponsive for 8 s"):
                it is killed first (SIGKILL, which also ends a stopped process). None: the
                child has exited, and how it ended is the reason.

        Returns:
            The /dev/shm files removed.
        """
        if child.proc is not None:
            if reason is not None and child.proc.poll() is None:
                child.proc.kill()
            child.proc.wait()
        removed = clean_shm(self.shm_before or set(), [])
        self.deaths.append({"node": child.name, "reason": reason or child.exit_reason(),
                            "shm_removed": len(removed)})
        child.restarts += 1
        if child.participant_id is not None:
            self.id_freed_at[child.participant_id] = time.monotonic()
        env = self.restart_env()
        child.participant_id = self.participant_ids[-1] if env is not self.env else None
        if child.participant_id is not None:
            self.id_freed_at.pop(child.participant_id, None)
        child.start(env)
        return removed

    def restart_env(self) -> dict[str, str]:
        """The environment of a restarted node: the graph's, with a participant id of
        ``RESTART_PARTICIPANT_IDS`` that no node restarted in this run has had and whose
        port file is not in /dev/shm (docs/reliability.md, "A restarted node's ports").

        Left to Fast DDS, the new process takes the lowest free id, the one of the process
        it replaces, and with it the same shared-memory port; that port's files are still
        open in the peers that were sending to the dead node, and a new listener racing with
        them for the port's lock can fail to open it ("Failed init_port ...:
        open_and_lock_file failed"), the message of every stall seen after a restart. A
        user's own profile (or transports) is left alone.
        """
        if self.env.get(PROFILE_ENV) != str(PROFILE_FILE):
            return self.env
        domain = int(self.env.get("ROS_DOMAIN_ID", "0"))
        taken = {name for name, _ in shm_files()}
        for pid in RESTART_PARTICIPANT_IDS:
            if pid in self.participant_ids:
                continue
            if f"fastrtps_port{user_unicast_port(domain, pid)}" in taken:
                continue  # another participant of this domain has (or had) that id
            return self._with_participant_id(pid)
        if self.id_freed_at:
            # Every id of the range given (a run of many restarts, ``roger chaos``): the id
            # whose process died longest ago, whose peers have had the most time to drop it.
            # Left to Fast DDS the new node would take the lowest free id, often the one of
            # the process it replaces, whose port is being raced for right now.
            return self._with_participant_id(min(self.id_freed_at,
                                                 key=self.id_freed_at.__getitem__))
        return self.env  # every id of the range in use: Fast DDS picks one

    def _with_participant_id(self, pid: int) -> dict[str, str]:
        """The graph's environment with a profile that fixes the participant id to
        ``pid`` (recorded as the last one given)."""
        if pid in self.participant_ids:
            self.participant_ids.remove(pid)
        self.participant_ids.append(pid)
        state = Path(self.env.get(STATE_DIR_ENV, self.out_dir / "state"))
        path = profile_with_participant_id(pid, state / "dds" / f"participant_{pid}.xml")
        return dict(self.env, **{PROFILE_ENV: str(path)})

    def stop(self, timeout: float = 10.0) -> list[str]:
        """SIGINT every child, wait, then SIGKILL what is left; clean what killed ones left.

        Returns:
            Names of the children that had to be killed.
        """
        for c in self.children:
            if c.alive():
                c.proc.send_signal(signal.SIGINT)  # type: ignore[union-attr]
                c.proc.send_signal(signal.SIGCONT)  # type: ignore[union-attr]  # if stopped
        deadline = time.monotonic() + timeout
        for c in self.children:
            if c.proc is None:
                continue
            try:
                c.proc.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                pass
        killed = []
        for c in self.children:
            if c.alive():
                c.proc.kill()  # type: ignore[union-attr]
                c.proc.wait()  # type: ignore[union-attr]
                killed.append(c.name)
        if killed:
            clean_shm(self.shm_before or set(), [])
        return killed


class StopRequested(Exception):
    """SIGINT or SIGTERM reached the orchestrator."""


class SignalGuard:
    """SIGINT/SIGTERM turned into StopRequested while installed; calling it restores the
    old handlers.

    The handler raises wherever the main thread is, which can be inside rclpy's C++ code
    converting a message (pybind11 then reports a RuntimeError instead of the
    StopRequested): ``received`` keeps the signal's name so that the caller can tell
    (``stop_requested``).
    """

    def __init__(self) -> None:
        self.received: str | None = None
        self._old = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
        for s in self._old:
            signal.signal(s, self._handler)

    def _handler(self, signum: int, frame: Any) -> None:
        self.received = signal.Signals(signum).name
        raise StopRequested(self.received)

    def stop_requested(self, exc: BaseException) -> StopRequested | None:
        """The StopRequested that ``exc`` stands for (None when no signal came)."""
        if isinstance(exc, StopRequested):
            return exc
        return StopRequested(self.received) if self.received is not None else None

    def __call__(self) -> None:
        for s, h in self._old.items():
            signal.signal(s, h)


def install_signal_handlers() -> SignalGuard:
    """Turn SIGINT/SIGTERM into StopRequested; the result restores the old handlers."""
    return SignalGuard()
