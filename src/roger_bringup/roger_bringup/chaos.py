"""``roger chaos``: one long graph run with faults at any moment, then a check of its files.

Three parts, each usable alone (docs/reliability.md, "Chaos run"):

- ``fault_schedule``: the seeded schedule, which node gets which signal at which cycle. Pure.
- ``FaultInjector``: a ``run.RunHook`` that sends those signals to the live node processes
  of ``run.run_graph``'s graph; the orchestrator's own restart and hung-node detection do
  the rest. Every fault goes to ``DIR/faults.jsonl`` as it is sent.
- ``check_run``: reads the finished run's files (cycles.csv, metrics.json, run_status.json,
  memory.pt, logs/memory.log, faults.jsonl, chaos_run.json) and returns what
  ``DIR/chaos.json`` holds. Pure: a doctored cycles.csv fails it.
"""

from __future__ import annotations

import csv
import json
import os
import re
import signal
import sys
import time
from collections import Counter
from dataclasses import asdict, dataclass
from enum import Enum
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from roger_bringup.orchestrator import NODES, Child, Graph, shm_files, shm_holders
from roger_common import topics
from roger_common.errors import ConfigError

#: Names of the graph's nodes, the targets of the schedule.
NODE_NAMES: tuple[str, ...] = tuple(name for name, _ in NODES)
#: Cycles recorded before the first fault: the graph is up and every node has been heard.
FIRST_FAULT_CYCLE = 3
#: Cycles a map-update fault waits for the attention node to send a STORE before it is
#: sent anyway (and recorded as not in a map update); it waits no longer than until the
#: next fault is due.
MAP_UPDATE_WAIT_CYCLES = 60
#: Wall seconds between two progress lines on stderr.
PROGRESS_PERIOD_S = 15.0
#: Wall seconds between two samples of which /dev/shm files the run's processes hold.
SHM_SAMPLE_PERIOD_S = 5.0
#: The memory node's log line of an acknowledged STORE (roger_memory.memory_node), written
#: after memory.pt and before the reply.
STORED_LINE = re.compile(r"(?:\[(\d+\.\d+)\] \[[^]]*\]: )?"
                         r"stored object at address (\d+) \((\d+) in memory\)")
#: Files of a chaos run, replaced when a new one starts in the same folder.
FAULTS_FILE = "faults.jsonl"
RUN_FILE = "chaos_run.json"
CHAOS_FILE = "chaos.json"


class FaultSignal(Enum):
    """How a node is hit."""

    KILL = "SIGKILL"  # dies at once, leaves its /dev/shm files
    TERM = "SIGTERM"  # shuts down cleanly (exit 0), restarted like a death
    STOP = "SIGSTOP"  # freezes, never resumed: the heartbeat watch kills and restarts it

    @property
    def signum(self) -> int:
        """The signal's number."""
        return int(getattr(signal, self.value))


@dataclass(frozen=True)
class Fault:
    """One scheduled fault.

    Attributes:
        index: Position in the schedule (0-based).
        cycle: Sent once cycles.csv holds this many cycles (and the node is up and heard).
        node: Target node (``NODE_NAMES``).
        signal: What it gets.
        map_update: Attention only: sent the moment the node has sent a STORE (the memory
            request of a map update), so that the node dies in the middle of that map update.
    """

    index: int
    cycle: int
    node: str
    signal: FaultSignal
    map_update: bool = False


def fault_schedule(cycles: int, faults: int, seed: int,
                   nodes: tuple[str, ...] = NODE_NAMES) -> tuple[Fault, ...]:
    """The seeded fault schedule of a chaos run.

    Fault cycles are spread over the run: one in each of ``faults`` equal stretches after
    ``FIRST_FAULT_CYCLE``, at a random place in its first 80 % (so at least one cycle apart).
    Targets go round in blocks of ``len(nodes)``, each block a random order of every node, so
    any ``len(nodes)`` faults in a row hit every node; each node's successive faults take the
    signals in a random order of the three, so ``3 * len(nodes)`` faults hit every
    node with every signal. Every other fault of the attention node (its first included) is
    a map-update fault.

    Raises:
        ConfigError: Fewer than one fault, or too few cycles to leave two per fault.
    """
    if faults < 1:
        raise ConfigError(f"--faults {faults}: must be at least 1")
    if cycles < FIRST_FAULT_CYCLE + 2 * faults + 2:
        raise ConfigError(f"--cycles {cycles}: too few for {faults} faults (at least "
                          f"{FIRST_FAULT_CYCLE + 2 * faults + 2})")
    rng = np.random.default_rng(seed)
    gap = (cycles - FIRST_FAULT_CYCLE - 2) / faults
    signals = list(FaultSignal)
    orders: dict[str, list[FaultSignal]] = {n: [] for n in nodes}
    hits: Counter[str] = Counter()
    out: list[Fault] = []
    targets: list[str] = []
    while len(targets) < faults:
        targets += [nodes[i] for i in rng.permutation(len(nodes))]
    for i, node in enumerate(targets[:faults]):
        if not orders[node]:
            orders[node] = [signals[j] for j in rng.permutation(len(signals))]
        sig = orders[node].pop(0)
        cycle = FIRST_FAULT_CYCLE + int(i * gap + rng.uniform(0.0, 0.8 * gap))
        map_update = node == "attention" and hits[node] % 2 == 0
        hits[node] += 1
        out.append(Fault(i, cycle, node, sig, map_update))
    return tuple(out)


class FaultInjector:
    """Sends the schedule's signals to the graph's node processes (a ``run.RunHook``).

    A fault waits until its cycle is recorded, at least one cycle has been recorded since
    the previous fault, and its node runs and has been heard on /diagnostics (a node
    stopped before its first beat would only be caught by the 60 s startup limit, a wait,
    not a hang). A map-update fault then arms a subscription to the memory requests and
    hits the attention node in the callback of its next STORE, before the memory has
    answered; after ``MAP_UPDATE_WAIT_CYCLES``, or once the next fault is due, without one
    it is sent anyway.
    """

    def __init__(self, faults: tuple[Fault, ...], out: Path, cycles: int,
                 log: TextIO | None = None) -> None:
        self.faults = faults
        self.out = out
        self.cycles = cycles
        self.log = sys.stderr if log is None else log
        self.next = 0
        self.injected: list[dict[str, Any]] = []
        #: Every pid of a node process seen in the run (the leftover check).
        self.pids: set[int] = set()
        #: /dev/shm files, (name, inode), seen held by a process of the run.
        self.shm_seen: set[tuple[str, int]] = set()
        self._graph: Graph | None = None
        self._cycles_seen = 0
        self._armed_at: int | None = None
        self._last_fault_cycle = -1
        self._last_progress = 0.0
        self._last_shm_sample = 0.0
        self._fh = open(out / FAULTS_FILE, "w")

    def attach(self, node: Any) -> None:
        """Listen to the memory requests (for map-update faults)."""
        from roger_common.ros_node import RELIABLE
        from roger_interfaces.msg import MemoryRequest
        node.create_subscription(MemoryRequest, topics.MEMORY_REQUEST, self._on_request,
                                 RELIABLE)

    def _on_request(self, msg: Any) -> None:
        from roger_common.types import MemoryOp
        if self._armed_at is None or self._graph is None or int(msg.op) != MemoryOp.STORE:
            return
        child = self._child("attention")
        if child is not None and child.alive():
            self._send(child, self.faults[self.next], True, request_id=int(msg.request_id))

    def tick(self, graph: Graph, cycles: int, watch: Any) -> None:
        """One turn of the run loop: send the fault that is due, if its node is ready."""
        self._graph = graph
        self._cycles_seen = cycles
        for c in graph.children:
            if c.proc is not None:
                self.pids.add(c.proc.pid)
        now = time.monotonic()
        if now - self._last_shm_sample > SHM_SAMPLE_PERIOD_S:
            self._last_shm_sample = now
            self._sample_shm(graph)
        if now - self._last_progress > PROGRESS_PERIOD_S:
            self._last_progress = now
            self.progress(graph)
        if self.next >= len(self.faults):
            return
        fault = self.faults[self.next]
        # A fault overdue (its node was not back yet, or a map-update fault waited) does
        # not drag the next ones along with it: one recorded cycle at least between two.
        if cycles < fault.cycle or cycles <= self._last_fault_cycle:
            return
        child = self._child(fault.node)
        if child is None or child.proc is None or not child.alive() \
                or watch.silent_for(child.proc.pid) is None:
            return  # not back yet from an earlier fault: wait until it is heard
        if not fault.map_update:
            self._send(child, fault, False)
        elif self._armed_at is None:
            self._armed_at = cycles
        elif cycles - self._armed_at >= MAP_UPDATE_WAIT_CYCLES or (
                self.next + 1 < len(self.faults) and cycles >= self.faults[self.next + 1].cycle):
            self._send(child, fault, False)  # no STORE came in time

    def _child(self, name: str) -> Child | None:
        if self._graph is None:
            return None
        return next((c for c in self._graph.children if c.name == name), None)

    def _send(self, child: Child, fault: Fault, in_map_update: bool,
              request_id: int | None = None) -> None:
        assert child.proc is not None
        pid = child.proc.pid
        try:
            os.kill(pid, fault.signal.signum)
        except ProcessLookupError:
            return  # died meanwhile: the orchestrator restarts it, the fault waits
        record = {"index": fault.index, "scheduled_cycle": fault.cycle,
                  "cycle": self._cycles_seen, "node": fault.node,
                  "signal": fault.signal.value, "pid": pid, "wall_time": time.time(),
                  "map_update_asked": fault.map_update, "in_map_update": in_map_update,
                  "store_request_id": request_id, "restarts_before": child.restarts}
        self.injected.append(record)
        self._fh.write(json.dumps(record) + "\n")
        self._fh.flush()
        self.next += 1
        self._armed_at = None
        self._last_fault_cycle = self._cycles_seen
        what = " in the middle of a map update (STORE sent)" if in_map_update else ""
        print(f"chaos: fault {self.next}/{len(self.faults)}: {fault.signal.value} to "
              f"{fault.node} (pid {pid}) at cycle {self._cycles_seen}{what}",
              file=self.log, flush=True)

    def progress(self, graph: Graph | None = None) -> None:
        """One line on stderr: faults injected, cycles done, restarts."""
        graph = graph or self._graph
        restarts = sum(c.restarts for c in graph.children) if graph is not None else 0
        print(f"chaos: {len(self.injected)}/{len(self.faults)} faults injected, "
              f"{self._cycles_seen}/{self.cycles} cycles done, {restarts} restarts",
              file=self.log, flush=True)

    def _sample_shm(self, graph: Graph) -> None:
        mine = {c.proc.pid for c in graph.children if c.proc is not None and c.alive()}
        mine.add(os.getpid())
        files = dict(shm_files())
        for name, pids in shm_holders().items():
            if pids & mine and name in files:
                self.shm_seen.add((name, files[name]))

    def close(self) -> None:
        """Close faults.jsonl."""
        self._fh.close()


def leftover_processes(out: Path, pids: set[int]) -> list[dict[str, Any]]:
    """Live processes of the run: any of ``pids``, or any process whose environment names
    the run's state folder (every node process of the run has it), zombies excluded."""
    state = f"ROGER_STATE_DIR={(out / 'state').resolve()}".encode()
    found = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit() or int(d.name) == os.getpid():
            continue
        try:
            status = (d / "stat").read_text().rsplit(")", 1)[1].split()[0]
            ours = int(d.name) in pids or state in (d / "environ").read_bytes().split(b"\0")
            cmd = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        if ours and status != "Z":
            found.append({"pid": int(d.name), "state": status, "cmdline": cmd.strip()})
    return found


def leftover_shm(before: set[tuple[str, int]], seen: set[tuple[str, int]],
                 domain: int) -> list[str]:
    """Fast DDS files in /dev/shm of the run: new since ``before``, and named after the
    run's domain or seen held by the run's processes (``seen``), that nobody holds now."""
    held = set(shm_holders())
    out = []
    for name, inode in sorted(shm_files() - before):
        m = re.search(r"fastrtps_port(\d+)", name)
        of_domain = m is not None and (int(m.group(1)) - 7400) // 250 == domain \
            and int(m.group(1)) >= 7400 + 250 * domain + 10
        if (of_domain or (name, inode) in seen) and name not in held:
            out.append(name)
    return out


def _rows(path: Path) -> list[dict[str, str]]:
    try:
        with open(path, newline="") as fh:
            return list(csv.DictReader(fh))
    except OSError:
        return []


def _json(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def acknowledged_stores(memory_log: Path) -> list[tuple[int, float | None]]:
    """(address, wall time of the log line or None) of every STORE the memory node
    acknowledged, in order (its log: every process of the run appended to the same file)."""
    try:
        text = memory_log.read_text(errors="replace")
    except OSError:
        return []
    return [(int(m.group(2)), float(m.group(1)) if m.group(1) else None)
            for m in STORED_LINE.finditer(text)]


def _nearest_fault(at: float | None, node: str, injected: list[dict[str, Any]]
                   ) -> dict[str, Any] | None:
    """The fault of ``node`` nearest in wall time to ``at``: its index, signal, whether it
    hit a map update, and ``after_s``, the seconds from ``at`` to the fault (negative: the
    fault came first). None: no fault of ``node``, or no time known."""
    if at is None:
        return None
    faults = [f for f in injected if f["node"] == node and "wall_time" in f]
    if not faults:
        return None
    f = min(faults, key=lambda f: abs(f["wall_time"] - at))
    return {"index": f["index"], "signal": f["signal"],
            "in_map_update": f.get("in_map_update", False),
            "after_s": round(f["wall_time"] - at, 3)}


def _foreign_rows(table: list[dict[str, str]], world: str | None) -> int:
    """Rows of cycles.csv whose true object is not an object of ``world`` (0 when the world
    file cannot be read: nothing to compare with)."""
    from roger_common.errors import WorldFileError
    from roger_sim.world import load_world
    if not world:
        return 0
    try:
        names = {o.name for o in load_world(Path(world)).objects}
    except (OSError, WorldFileError):
        return 0
    return sum(1 for r in table if r.get("true_object") and r["true_object"] not in names)


def check_run(out: Path) -> dict[str, Any]:
    """Check a finished chaos run from its files; the result is chaos.json.

    Checks (each failing one is named in ``failed``): every scheduled fault injected and
    every node hit; no stall nor other run error; cycles.csv holds every cycle 1..N exactly
    once (N: the cycles asked for if the run completed, else the last recorded); Table 2's
    counters of metrics.json equal those recomputed from cycles.csv and its identities hold;
    every STORE the memory acknowledged (logs/memory.log) is in memory.pt and is a
    ``stored`` cycle of cycles.csv, and every ``stored`` cycle is in memory.pt; no address
    stored twice and no two identical stored looks in memory.pt; no row about an object
    the world has not (another graph on the same domain); no process and no /dev/shm file
    of the run left (measured after the run, in chaos_run.json).
    """
    from roger_common.errors import MemoryFileError
    from roger_experiments.evaluation import counters_from_rows, rows_from_csv
    from roger_memory.persistence import load_snapshot

    run = _json(out / RUN_FILE)
    status = _json(out / "run_status.json")
    metrics = _json(out / "metrics.json")
    injected = [json.loads(line) for line in (out / FAULTS_FILE).read_text().splitlines()
                if line.strip()] if (out / FAULTS_FILE).exists() else []
    failed: list[str] = []
    asked = int(run.get("cycles", 0))
    scheduled = int(run.get("faults", 0))
    error = run.get("run_error")
    stalls = 1 if error and "stalled" in error else 0
    if len(injected) < scheduled:
        failed.append(f"faults: {len(injected)} of {scheduled} injected")
    hit = Counter(f["node"] for f in injected)
    if scheduled >= len(NODE_NAMES) and set(hit) != set(NODE_NAMES):
        failed.append(f"faults: nodes never hit: {sorted(set(NODE_NAMES) - set(hit))}")
    if stalls:
        failed.append(f"stalls: {error}")
    elif error:
        failed.append(f"run error: {error}")
    # Cycles: each once.
    table = _rows(out / "cycles.csv")
    numbers = [int(r["cycle"]) for r in table if r.get("cycle", "").isdigit()]
    counts = Counter(numbers)
    completed = not error and bool(status.get("status", "").startswith(("done", "complete")))
    last = asked if completed else max(numbers, default=0)
    lost_cycles = sorted(set(range(1, last + 1)) - set(numbers))
    duplicate_cycles = sorted(n for n, k in counts.items() if k > 1)
    if lost_cycles:
        failed.append(f"lost_cycles: {len(lost_cycles)} cycles missing from cycles.csv "
                      f"(first {lost_cycles[:10]})")
    if duplicate_cycles:
        failed.append(f"duplicate cycles in cycles.csv: {duplicate_cycles[:10]}")
    if not completed and not error:
        failed.append(f"run: did not complete (status {status.get('status')!r})")
    if completed and asked and len(numbers) != asked:
        failed.append(f"cycles: {len(numbers)} rows, {asked} asked")
    # Rows about objects the world has not: another graph on the run's ROS domain (it
    # happened: a concurrent `roger run` drew the same random domain, docs/reliability.md).
    foreign = _foreign_rows(table, run.get("world"))
    if foreign:
        failed.append(f"foreign_rows: {foreign} rows name objects not in "
                      f"{run.get('world')} (another graph on the same ROS domain?)")
    # Table 2's identities, and metrics.json against cycles.csv.
    try:
        rows = rows_from_csv(table)
    except (KeyError, ValueError) as exc:
        rows = []
        failed.append(f"cycles.csv: unreadable row: {exc}")
    recomputed = counters_from_rows(rows)
    table2_mismatch = {k: (metrics.get(k), v) for k, v in recomputed.items()
                       if metrics.get(k) != v}
    identities = (recomputed["attention_shifts"] + recomputed["improvements"]
                  + recomputed["map_updates"] == recomputed["cycles"]
                  and recomputed["map_updates"] == recomputed["positive_identifications"]
                  + recomputed["new_objects"] + recomputed["remaps"])
    if table2_mismatch:
        failed.append(f"table2: metrics.json differs from cycles.csv: {table2_mismatch}")
    if not identities:
        failed.append(f"table2: identities do not hold: {recomputed}")
    # Stores.
    acks = acknowledged_stores(out / "logs" / "memory.log")
    acked = [a for a, _ in acks]
    acked_at = {a: t for a, t in acks}
    csv_stored = [int(r["address"]) for r in table
                  if r.get("action") == "map_update" and r.get("outcome") == "stored"]
    try:
        snapshot = load_snapshot(out / "memory.pt")
        stored_mask = np.asarray(snapshot.stored, bool)
        in_file = set(np.asarray(snapshot.addresses)[stored_mask].tolist())
        looks = np.asarray(snapshot.exemplars)[stored_mask]
        identical_looks = len(looks) - len(np.unique(looks, axis=0)) if len(looks) else 0
        n_addresses = int(snapshot.n_addresses)
    except (OSError, MemoryFileError) as exc:
        in_file, identical_looks, n_addresses = set(), 0, 0
        if acked or csv_stored:
            failed.append(f"memory.pt: {exc}")
    lost_stores = []
    for address in sorted(set(acked) | set(csv_stored)):
        missing = [name for name, where in (("memory.pt", in_file),
                                            ("cycles.csv", csv_stored)) if address not in where]
        if address in acked and missing:
            # The attention fault nearest to the acknowledgement: a STORE in flight?
            lost_stores.append({"address": address, "missing_from": missing,
                                "nearest_attention_fault": _nearest_fault(
                                    acked_at[address], "attention", injected)})
        elif address not in acked and address not in in_file:
            lost_stores.append({"address": address, "missing_from": ["memory.pt"],
                                "acknowledged": False})
    duplicate_stores = (identical_looks
                        + sum(k - 1 for k in Counter(csv_stored).values() if k > 1)
                        + sum(k - 1 for k in Counter(acked).values() if k > 1))
    if lost_stores:
        failed.append(f"lost_stores: {len(lost_stores)} stores not where they belong: "
                      f"{lost_stores[:5]}")
    if duplicate_stores:
        failed.append(f"duplicate_stores: {duplicate_stores} (identical stored looks "
                      f"{identical_looks}, addresses stored twice in cycles.csv or the "
                      "memory log)")
    procs = run.get("leftover_processes", [])
    shm = run.get("leftover_shm", [])
    if procs:
        failed.append(f"leftover_processes: {procs}")
    if shm:
        failed.append(f"leftover_shm: {shm}")
    deaths = status.get("deaths", [])
    restarts = sum(int(v) for v in status.get("restarts", {}).values())
    return {
        "seed": run.get("seed"), "world": run.get("world"),
        "cycles_asked": asked, "cycles_recorded": len(numbers),
        "faults_scheduled": scheduled, "faults": len(injected),
        "faults_by_node": dict(sorted(hit.items())),
        "faults_by_signal": dict(sorted(Counter(f["signal"] for f in injected).items())),
        "faults_in_map_update": sum(1 for f in injected if f.get("in_map_update")),
        "restarts": restarts,
        "restarts_without_fault": max(0, len(deaths) - len(injected)),
        "death_reasons": dict(sorted(Counter(
            d["reason"] if not d["reason"].startswith("unresponsive") else "unresponsive"
            for d in deaths).items())),
        "stalls": stalls, "run_error": error,
        "lost_cycles": len(lost_cycles), "duplicate_cycles": len(duplicate_cycles),
        "lost_stores": len(lost_stores), "lost_store_details": lost_stores,
        "duplicate_stores": duplicate_stores, "foreign_rows": foreign,
        "stores_acknowledged": len(acked), "stores_in_cycles_csv": len(csv_stored),
        "memory_addresses": n_addresses,
        "table2_identities": identities and not table2_mismatch,
        "leftover_processes": len(procs), "leftover_shm": len(shm),
        "wall_seconds": run.get("wall_seconds"),
        "ok": not failed, "failed": failed,
    }


@dataclass
class ChaosOptions:
    """Everything ``roger chaos`` takes."""

    world: Path
    cycles: int
    faults: int
    seed: int
    out: Path
    policy: str = "qlearning"
    domain_id: int | None = None


def run_chaos(opt: ChaosOptions, log: TextIO | None = None) -> dict[str, Any]:
    """Run the graph with the seeded faults, check its files, write DIR/chaos.json.

    The folder starts afresh: an earlier run's memory, Q-table, logs and chaos files there
    are removed (``roger run`` would resume from them).

    Returns:
        chaos.json's content (``ok`` False when a check failed, ``failed`` says which).
    """
    from roger_bringup.orchestrator import pick_domain_id
    from roger_bringup.run import RunError, RunOptions, run_graph

    log = sys.stderr if log is None else log
    schedule = fault_schedule(opt.cycles, opt.faults, opt.seed)
    out = opt.out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    for name in ("memory.pt", "qtable.json", CHAOS_FILE, RUN_FILE, FAULTS_FILE):
        (out / name).unlink(missing_ok=True)
    for old in (out / "logs").glob("*.log"):
        old.unlink()
    domain = opt.domain_id if opt.domain_id is not None else pick_domain_id()
    injector = FaultInjector(schedule, out, opt.cycles, log)
    with open(out / "schedule.json", "w") as fh:
        json.dump([dict(asdict(f), signal=f.signal.value) for f in schedule], fh, indent=1)
    run_opt = RunOptions(
        world=opt.world, out=out, policy=opt.policy, cycles=opt.cycles, seed=opt.seed,
        domain_id=domain, progress=False, max_restarts=opt.faults + 3, hook=injector,
        # The usual budget plus room for each restart (a frozen node is caught after 8 s).
        timeout_s=120.0 + 3.0 * opt.cycles + 30.0 * opt.faults)
    print(f"roger chaos: {opt.faults} faults over {opt.cycles} cycles, seed {opt.seed}, "
          f"ROS_DOMAIN_ID={domain}, output {out}", file=log, flush=True)
    before = shm_files()
    t0 = time.monotonic()
    error: str | None = None
    try:
        run_graph(run_opt, log=log)
    except RunError as exc:
        error = str(exc).splitlines()[0]
        print(f"roger chaos: the run ended early: {exc}", file=log, flush=True)
    finally:
        injector.close()
        injector.progress()
        procs = leftover_processes(out, injector.pids)
        shm = leftover_shm(before, injector.shm_seen, domain)
        with open(out / RUN_FILE, "w") as fh:
            json.dump({"cycles": opt.cycles, "faults": opt.faults, "seed": opt.seed,
                       "world": str(opt.world.resolve()), "domain_id": domain,
                       "run_error": error,
                       "wall_seconds": round(time.monotonic() - t0, 1),
                       "leftover_processes": procs, "leftover_shm": shm}, fh, indent=2)
        # Counted above; now ended and removed, so that a failed check leaves no mess.
        for p in procs:
            try:
                os.kill(p["pid"], signal.SIGKILL)
            except OSError:
                pass
        for name in shm:
            try:
                os.unlink(f"/dev/shm/{name}")
            except OSError:
                pass
    result = check_run(out)
    with open(out / CHAOS_FILE, "w") as fh:
        json.dump(result, fh, indent=2)
    return result


__all__ = ["ChaosOptions", "Fault", "FaultInjector", "FaultSignal", "check_run",
           "fault_schedule", "run_chaos"]
