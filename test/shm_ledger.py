"""Which Fast DDS files in /dev/shm a test's own graph left behind (the leak check).

Several Roger graphs may run on one machine at once (a test run, a user's ``roger run``, a
second CI job), and their files sit side by side in /dev/shm. The leak check must blame a
test only for files of its own graph. Fast DDS 2.14, as Roger configures it, makes three
kinds (measured; docs/reliability.md):

* ``fastrtps_port<N>`` (+ ``_el``, + ``sem.fastrtps_port<N>_mutex``) of rmw's built-in
  shared-memory transport, where N is an RTPS port, ``7400 + 250 * domain + offset``
  (offset < 250): the name says the domain.
* the same names with N = 7000, 7001, ... for the 4 MiB transport of Roger's profile: the
  first free port on the machine, whatever the domain. The name says nothing.
* ``fastrtps_<16 hex>`` (+ ``_el``): a participant's segment. The name says nothing.

So a file is the test's own when its name says one of the test's domains, or, for the two
other kinds, when the processes seen holding it (open or mapped) the last time anyone was
seen holding it belonged to the test's process tree. Processes of different domains never
map each other's files, so another graph's files are never held by the test's processes,
and the holders are sampled while the test runs (``ShmLedger.start``). The ``sem.`` and
``_el`` companions, which nobody keeps open, go with their port or segment. Records are
per inode, so a port number reused by another graph after the test's one closed is not
mistaken for the test's.

What this cannot see: a file of the test's graph whose holders all lived less than one
sampling interval (a leak missed, never a file blamed on the wrong graph).
"""

from __future__ import annotations

import os
import re
import threading
from collections.abc import Iterable
from pathlib import Path

from roger_bringup.orchestrator import shm_group as group_of  # one rule for both
from roger_bringup.orchestrator import shm_holders

SHM = Path("/dev/shm")
#: RTPS well-known ports: PB + DG * domain + offset (offset < DG).
PORT_BASE = 7400
DOMAIN_GAIN = 250
_PORT = re.compile(r"fastrtps_port(\d+)")


def shm_files() -> dict[str, int]:
    """Fast DDS files in /dev/shm, with their inode."""
    out = {}
    try:
        entries = list(os.scandir(SHM))
    except FileNotFoundError:
        return out
    for e in entries:
        if _is_dds(e.name):
            try:
                out[e.name] = e.inode()
            except OSError:
                continue
    return out


def domain_of(name: str) -> int | None:
    """The DDS domain a file's name says, or None when the name says none."""
    m = _PORT.fullmatch(group_of(name))
    if m is None or int(m[1]) < PORT_BASE:
        return None
    return (int(m[1]) - PORT_BASE) // DOMAIN_GAIN


def _is_dds(name: str) -> bool:
    return "fastrtps" in name or "fastdds" in name


def holders() -> dict[str, set[int]]:
    """Fast DDS files in /dev/shm by the live processes that have them open or mapped."""
    return {name: pids for name, pids in shm_holders().items() if _is_dds(name)}


def process_tree(roots: Iterable[int]) -> set[int]:
    """``roots`` and every live descendant of them."""
    children: dict[int, list[int]] = {}
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            fields = (d / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        children.setdefault(int(fields[1]), []).append(int(d.name))
    tree, todo = set(roots), list(roots)
    while todo:
        for c in children.get(todo.pop(), []):
            if c not in tree:
                tree.add(c)
                todo.append(c)
    return tree


class ShmLedger:
    """Records, while a test runs, whose process tree holds each Fast DDS file.

    Args:
        roots: The processes whose trees are "the test's own" (default: this process).
        interval: Seconds between two samples of the background thread (``start``).
    """

    def __init__(self, roots: Iterable[int] | None = None, interval: float = 0.5) -> None:
        self.roots = set(roots) if roots is not None else {os.getpid()}
        self.interval = interval
        self.before = set(shm_files().items())
        #: (name, inode) -> whether the test's tree held its group at the latest sample
        #: that saw anyone holding it.
        self._ours: dict[tuple[str, int], bool] = {}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def sample(self) -> None:
        """Note who holds each file now."""
        with self._lock:
            tree = process_tree(self.roots)
            group_ours: dict[str, bool] = {}
            for name, pids in holders().items():
                g = group_of(name)
                group_ours[g] = group_ours.get(g, False) or bool(pids & tree)
            for name, inode in shm_files().items():
                ours = group_ours.get(group_of(name))
                if ours is not None:
                    self._ours[(name, inode)] = ours

    def leaked(self, domains: Iterable[int]) -> list[str]:
        """Files of the test's graph that appeared since the ledger was made (by name and
        inode) and of whose port or segment no live process holds any file.

        Args:
            domains: The DDS domains the test's graph used.
        """
        self.sample()
        domains = set(domains)
        held = {group_of(name) for name in holders()}
        out = []
        for name, inode in shm_files().items():
            if (name, inode) in self.before or group_of(name) in held:
                continue
            domain = domain_of(name)
            if domain is not None:
                ours = domain in domains
            else:
                ours = self._ours.get((name, inode), False)
            if ours:
                out.append(name)
        return sorted(out)

    def start(self) -> ShmLedger:
        """Sample every ``interval`` seconds in a background thread until ``stop``."""
        def loop() -> None:
            while not self._stop.wait(self.interval):
                self.sample()
        self.sample()
        self._thread = threading.Thread(target=loop, name="shm-ledger", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """End the background sampling."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()


def domains_in_use() -> set[int]:
    """Domains whose port files are in /dev/shm now (another graph may be on them)."""
    return {d for d in map(domain_of, shm_files()) if d is not None}
