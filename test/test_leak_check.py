"""The leak check blames a test for its own graph's files in /dev/shm, and only for those.

Two stand-in graphs (``dds_graph.py``: two rclpy participants each) run side by side on two
domains, each a process tree of its own. In each, one participant is killed with SIGKILL
and the other stops cleanly, which leaves files of every kind in /dev/shm (``shm_ledger``
lists them): port files named after the domain, port files of Roger's profile transport
(7000, 7001...) and participant segments. A ledger rooted at one graph must claim exactly
what that graph left, and nothing the other left, although the old check (new and
unheld) blamed both on the test.
"""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from conftest import SESSION_DOMAIN, free_domain
from shm_ledger import SHM, ShmLedger, domain_of, group_of, holders, process_tree, shm_files

HERE = Path(__file__).resolve().parent


def test_a_port_file_name_says_its_domain() -> None:
    assert domain_of("fastrtps_port9161") == 7  # 7400 + 250 * 7 + 11
    assert domain_of("sem.fastrtps_port12411_mutex") == 20
    assert domain_of("fastrtps_port12413_el") == 20
    assert domain_of("fastrtps_port7000") is None  # Roger's profile transport: any domain
    assert domain_of("sem.fastrtps_port7001_mutex") is None
    assert domain_of("fastrtps_4cce2f0a67eba4d4_el") is None  # a participant's segment
    assert group_of("sem.fastrtps_port7001_mutex") == "fastrtps_port7001"
    assert group_of("fastrtps_4cce2f0a67eba4d4_el") == "fastrtps_4cce2f0a67eba4d4"


def test_a_file_named_after_the_tests_domain_is_caught(no_leaks) -> None:
    # Nobody ever holds a port's mutex file: only its name can place it.
    ours = SHM / f"sem.fastrtps_port{7400 + 250 * SESSION_DOMAIN + 248}_mutex"
    other_domain = free_domain({SESSION_DOMAIN})
    theirs = SHM / f"sem.fastrtps_port{7400 + 250 * other_domain + 248}_mutex"
    ledger = ShmLedger()
    try:
        ours.write_bytes(b"\0" * 32)
        theirs.write_bytes(b"\0" * 32)
        assert ledger.leaked({SESSION_DOMAIN}) == [ours.name]
        assert ledger.leaked({other_domain}) == [theirs.name]
    finally:
        ours.unlink(missing_ok=True)
        theirs.unlink(missing_ok=True)


@dataclass
class StandIn:
    """A stand-in graph: a launcher process and its participants."""

    domain: int
    proc: subprocess.Popen
    pids: list[int] = field(default_factory=list)
    lines: queue.Queue = field(default_factory=queue.Queue)
    said: list[str] = field(default_factory=list)

    @classmethod
    def start(cls, domain: int, n: int = 2) -> StandIn:
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain))
        proc = subprocess.Popen([sys.executable, str(HERE / "dds_graph.py"), str(n)],
                                env=env, stdout=subprocess.PIPE, text=True)
        graph = cls(domain, proc)
        threading.Thread(target=lambda: [graph.lines.put(ln) for ln in proc.stdout],
                         daemon=True).start()
        return graph

    def wait_ready(self, n: int = 2, timeout: float = 60.0) -> None:
        """Until every participant has heard from another (each maps the others' files).

        Raises:
            AssertionError: Not all ready within ``timeout`` s; the message says what the
                test saw (``seen``), so that a failure to discover can be told apart.
        """
        ready = 0
        deadline = time.monotonic() + timeout
        while ready < n:
            try:
                line = self.lines.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                raise AssertionError(f"stand-in graph on domain {self.domain}: {ready} of {n} "
                                     f"participants ready after {timeout:g} s; "
                                     f"{self.seen()}") from None
            self.said.append(line.rstrip())
            # By word, not by line: lines of two writers on one pipe may run together.
            words = line.split()
            for word, value in zip(words, words[1:], strict=False):
                if word.endswith("pid") and value.isdigit():
                    self.pids.append(int(value))
                elif word.endswith("ready") and value.isdigit():
                    ready += 1

    def seen(self) -> str:
        """What the graph looks like now: its lines, each participant's state and sockets,
        and the shared-memory files of its domain and of its processes, with their holders.
        A participant's UDP ports say its participant id (7400 + 250 * domain + 10/11 +
        2 * id): two ids of 32 or more never discover each other with LOCALHOST discovery
        (roger_common.dds), and a port file held by a process of another graph means the
        domain was not free."""
        mine = process_tree([self.proc.pid])
        parts = [f"launcher {self.proc.pid} exit {self.proc.poll()}",
                 f"lines {self.said}"]
        for pid in self.pids:
            parts.append(f"participant {pid}: {_proc_state(pid)}, udp ports "
                         f"{sorted(_udp_ports(pid))}")
        held = holders()
        files = sorted(name for name in shm_files()
                       if domain_of(name) == self.domain or held.get(name, set()) & mine)
        parts.append("shm " + ", ".join(
            f"{name} held by {sorted(held.get(name, ()))}" for name in files))
        return "; ".join(parts)

    def files(self) -> set[str]:
        """The ports and segments this graph's processes have open or mapped now."""
        return {group_of(name) for name, pids in holders().items() if pids & set(self.pids)}

    def end(self) -> None:
        # Its participants whether or not they said their pid (a launcher that timed out
        # before they did must not leave them running).
        for pid in set(self.pids) | (process_tree([self.proc.pid]) - {self.proc.pid}):
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait(timeout=30)


def _proc_state(pid: int) -> str:
    """A process's state letter (R, S, T, Z...) or "gone"."""
    try:
        return (Path("/proc") / str(pid) / "stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return "gone"


def _udp_ports(pid: int) -> set[int]:
    """The UDP ports the process has bound (its sockets' inodes in /proc/net/udp)."""
    try:
        inodes = {os.readlink(fd)[8:-1] for fd in Path(f"/proc/{pid}/fd").iterdir()
                  if os.readlink(fd).startswith("socket:[")}
    except OSError:
        return set()
    ports = set()
    for table in ("udp", "udp6"):
        try:
            rows = Path(f"/proc/{pid}/net/{table}").read_text().splitlines()[1:]
        except OSError:
            continue
        for row in rows:
            cols = row.split()
            if len(cols) > 9 and cols[9] in inodes:
                ports.add(int(cols[1].rsplit(":", 1)[1], 16))
    return ports


def left_unheld(ledger: ShmLedger, groups: set[str]) -> set[str]:
    """Files of ``groups`` created since ``ledger`` was made, of a port or segment that
    nobody holds now."""
    held = {group_of(name) for name in holders()}
    return {name for name, inode in shm_files().items()
            if (name, inode) not in ledger.before and group_of(name) not in held
            and group_of(name) in groups}


def test_each_graph_is_blamed_for_its_own_files_only(no_leaks) -> None:
    own_domain = free_domain({SESSION_DOMAIN})
    other_domain = free_domain({SESSION_DOMAIN, own_domain})
    mine = ShmLedger()  # this test's whole tree: what it must clean up at the end
    ledgers = {d: ShmLedger(roots=()) for d in (own_domain, other_domain)}
    graphs: dict[int, StandIn] = {}
    try:
        for d in ledgers:
            graphs[d] = StandIn.start(d)
        for d, graph in graphs.items():
            graph.wait_ready()
            ledgers[d].roots = {graph.proc.pid}
        files = {d: g.files() for d, g in graphs.items()}
        assert not files[own_domain] & files[other_domain], \
            sorted(files[own_domain] & files[other_domain])
        for ledger in (mine, *ledgers.values()):
            ledger.sample()
        for graph in graphs.values():
            os.kill(graph.pids[0], signal.SIGKILL)
            os.kill(graph.pids[1], signal.SIGINT)
            assert graph.proc.wait(timeout=60) == 0
        left = {d: left_unheld(mine, files[d]) for d in graphs}
        for d in graphs:
            # The killed participant left files of every kind, some of them unplaceable by
            # name: the old check (new and unheld) blamed them on whichever test ran.
            assert any(domain_of(f) == d for f in left[d]), left[d]
            assert any(domain_of(f) is None and "port" in f for f in left[d]), left[d]
            assert any(domain_of(f) is None and "port" not in f for f in left[d]), left[d]
        # Each ledger catches all its graph left and nothing of the other's.
        assert set(ledgers[own_domain].leaked({own_domain})) == left[own_domain]
        assert set(ledgers[other_domain].leaked({other_domain})) == left[other_domain]
    finally:
        mine.sample()
        for graph in graphs.values():
            graph.end()
        for name in mine.leaked({own_domain, other_domain}):
            (SHM / name).unlink(missing_ok=True)
