"""``roger run``: one run of the multi-process graph, recorded to an output folder."""

from __future__ import annotations

import json
import os
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol, TextIO

import rclpy
import yaml
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions

from roger_attention.qlearning import QTable
from roger_bringup.monitor_node import MonitorNode
from roger_bringup.orchestrator import (
    STATE_DIR_ENV,
    Graph,
    StopRequested,
    clean_shm,
    install_signal_handlers,
    pick_domain_id,
    ros_environment,
    shm_files,
)
from roger_common.dds import PROFILE_ENV
from roger_common.errors import ConfigError, MemoryFileError, RogerError
from roger_common.liveness import HANG_TIMEOUT_S, SETUP_EXIT
from roger_common.ros_node import HeartbeatWatch
from roger_common.types import DEFAULT_FEATURE_MODE, FeatureMode
from roger_experiments.evaluation import CycleRow, RunRecorder
from roger_experiments.progress import ProgressBar, counters_info
from roger_memory.persistence import load_snapshot, snapshot_mode
from roger_sim.world import load_world

#: Wall seconds the graph may take to come up.
STARTUP_TIMEOUT_S = 60.0
#: Restarts allowed per node before the run gives up.
MAX_RESTARTS = 3
#: Wall seconds after which the attention node re-sends an unanswered goal or request in a
#: run (the node's own default, 10 s, is for a graph started by hand): a restarted peer is
#: back within a few seconds, and re-sent goals and requests are answered only once.
RETRY_AFTER_S = 3.0
#: Wall seconds without a new cycle (once cycling) after which the run is declared stalled.
STALL_S = 90.0
#: Wall seconds between the run loop's checks of the node processes and progress updates.
CHECK_PERIOD_S = 0.05
#: Wall seconds to wait, once the attention node said "done", for the cycles it reported
#: and this process has not received yet (Fast DDS repairs a lost sample at the writer's
#: next heartbeat, 3 s apart by default).
DONE_WAIT_S = 15.0


class RunHook(Protocol):
    """Something that runs beside the graph in the orchestrator's loop (``roger chaos``'s
    fault injector): it gets the monitor node once (to subscribe to topics; its callbacks
    run in the orchestrator's executor) and then every turn of the run loop."""

    def attach(self, node: Any) -> None:
        """Called once the monitor node exists, before any node process starts."""

    def tick(self, graph: Graph, cycles: int, watch: HeartbeatWatch) -> None:
        """Called every ``CHECK_PERIOD_S`` of the run loop, after the node checks, with the
        cycles recorded so far."""


class RunError(RogerError):
    """The run could not complete (a node failed to start, or the graph stalled)."""


@dataclass
class RunOptions:
    """Everything ``roger run`` takes (see ``roger run --help``)."""

    world: Path
    out: Path
    policy: str = "straightforward"
    cycles: int | None = 60
    until_complete: bool = False
    stable_cycles: int = 40
    max_cycles: int = 2000
    seed: int = 0
    qtable: Path | None = None
    memory: Path | None = None
    learn: bool = True
    #: Feature mode of perception and memory (``roger_common.types.FeatureMode``).
    features: str = DEFAULT_FEATURE_MODE.value
    #: Simulator shortcuts: None leaves the value to ``params_file`` (or the default).
    image_size: int | None = None
    realtime: bool | None = None
    gui: bool | None = None
    #: A standard ROS 2 parameters file handed to every node (``--params-file``).
    params_file: Path | None = None
    domain_id: int | None = None
    timeout_s: float | None = None
    progress: bool = True
    extra_params: dict[str, list[str]] = field(default_factory=dict)
    view: Path | None = None
    record: Path | None = None
    #: Serve every topic on a Foxglove WebSocket server at this port (0: a free one);
    #: None: no server. ``foxglove_host``: its address (loopback by default).
    foxglove: int | None = None
    foxglove_host: str = "127.0.0.1"
    external: tuple[str, ...] = ()
    #: Wall seconds without a heartbeat after which a node is killed and restarted; None
    #: turns the watch off (a node held at a debugger's breakpoint is not killed).
    hang_timeout_s: float | None = HANG_TIMEOUT_S
    #: Restarts allowed per node before the run gives up (``roger chaos`` raises it).
    max_restarts: int = MAX_RESTARTS
    #: Called beside the run loop (``RunHook``); None: nothing.
    hook: RunHook | None = None

    def budget(self) -> int:
        """Cycle budget handed to the attention node (with ``until_complete``, the most a
        run that never completes may take)."""
        return int(self.cycles or self.max_cycles)


def check_params_file(path: Path) -> None:
    """Refuse a parameters file a node would misread, naming the file and the key: it must
    be a YAML mapping of node names to ``{ros__parameters: {...}}``, and under a Roger
    node's own name every parameter must be one that node declares (rclpy would ignore a
    misspelt one silently). Values are checked by the nodes (a bad one stops the run with
    the node's one line).

    Raises:
        ConfigError: The file is missing, not YAML, or holds a key no node declares.
    """
    from roger_bringup.paramdoc import BUILTIN, parameter_table
    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise ConfigError(f"{path}: {exc}") from exc
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: must be a mapping of node names to ros__parameters")
    known: dict[str, set[str]] = {}
    for row in parameter_table():
        known.setdefault(row.node, set()).add(row.name)

    def flat(d: dict[str, Any], prefix: str = "") -> list[str]:
        out: list[str] = []
        for k, v in d.items():
            out += flat(v, f"{prefix}{k}.") if isinstance(v, dict) else [f"{prefix}{k}"]
        return out
    for node, section in data.items():
        params = section.get("ros__parameters") if isinstance(section, dict) else None
        if not isinstance(params, dict):
            raise ConfigError(f"{path}: {node}: must hold a ros__parameters mapping")
        for name in flat(params):
            if node in known and name not in known[node] | BUILTIN:
                raise ConfigError(f"{path}: {node}.ros__parameters.{name}: {node} has no "
                                  "such parameter (docs/parameters.md lists them)")


def _node_params(opt: RunOptions, world: Path, memory: Path, qtable: Path,
                 observers: int, out: Path,
                 light: tuple[float, float, float] = (1.0, 0.5, 1.0)
                 ) -> dict[str, list[str]]:
    """Each node's ``--ros-args`` after ``use_sim_time``: the run's own values as ``-p``.

    Perception is told the world file's ``light`` (``PerceptionConfig.light_direction``:
    the robot knows its light as it knows its camera), and with a params file that sets
    the simulator's ``light_ambient`` or ``light_diffuse``, those too.

    With ``opt.params_file`` every node also gets ``--params-file OUT/params.yaml``: the
    user's file with the run's own values written into each node's section (rcl lets a
    params file win over ``-p``, whatever their order, so the run's values must be in the
    file to win). OUT/params.yaml is kept: the exact parameters of the run.
    """
    values: dict[str, dict[str, Any]] = {
        "sim": dict(world=world, seed=opt.seed, image_size=opt.image_size,
                    realtime=opt.realtime, gui=opt.gui),
        "perception": dict(features=opt.features, light_direction=list(light)),
        "memory": dict(memory_file=memory, seed=opt.seed, features=opt.features),
        "attention": dict(policy=opt.policy, seed=opt.seed, max_cycles=opt.budget(),
                          stop_when_complete=opt.stable_cycles if opt.until_complete else 0,
                          qtable_file=qtable, learn=opt.learn, wait_for_observers=observers,
                          retry_after_s=RETRY_AFTER_S),
    }
    values = {n: {k: str(v) if isinstance(v, Path) else v for k, v in kv.items()
                  if v is not None} for n, kv in values.items()}
    head: list[str] = []
    if opt.params_file is not None:
        merged = yaml.safe_load(opt.params_file.read_text()) or {}
        sim_section = (merged.get("roger_sim") or {}).get("ros__parameters") or {}
        for name in ("light_ambient", "light_diffuse"):
            if name in sim_section:
                values["perception"][name] = sim_section[name]
        for node, kv in values.items():
            section = merged.setdefault(f"roger_{node}", {}).setdefault("ros__parameters", {})
            section.update(kv)
        path = out / "params.yaml"
        path.write_text(yaml.safe_dump(merged, sort_keys=False))
        head = ["--params-file", str(path)]
    params: dict[str, list[str]] = {}
    for node, kv in values.items():
        params[node] = list(head)
        for k, v in kv.items():
            params[node] += ["-p", f"{k}:={str(v).lower() if isinstance(v, bool) else v}"]
    for name, extra in opt.extra_params.items():
        params.setdefault(name, []).extend(extra)
    return params


class ResumingRecorder(RunRecorder):
    """A RunRecorder that keeps one row per cycle number.

    A restarted attention node re-sends its last report (it cannot know whether it went
    out before the crash); the copy of a cycle already recorded is dropped.
    """

    duplicates = 0

    def add(self, row: CycleRow) -> None:
        """Record a cycle unless its number is already recorded."""
        if self.rows and row.cycle <= self.rows[-1].cycle:
            self.duplicates += 1
            return
        super().add(row)


def check_files(memory: Path, qtable: Path, features: str = DEFAULT_FEATURE_MODE.value
                ) -> None:
    """Refuse a corrupt memory or Q-table file, or a memory of another feature mode,
    before anything starts (one line each).

    Raises:
        MemoryFileError: Naming the file and what is wrong with it.
    """
    if memory.exists():
        saved = snapshot_mode(load_snapshot(memory).config)
        if saved is not FeatureMode.parse(features):
            raise MemoryFileError(
                f"{memory}: a memory of {saved.value}-mode features, but this run uses the "
                f"{FeatureMode.parse(features).value} mode; run with --features "
                f"{saved.value}, or give another --memory file")
    if qtable.exists():
        QTable.load(qtable)


def run_graph(opt: RunOptions, log: TextIO | None = None) -> dict[str, Any]:
    """Run the graph once and write ``cycles.csv`` and ``metrics.json`` to ``opt.out``.

    Returns:
        The metrics written to metrics.json.

    Raises:
        WorldFileError: The world file is unusable (before anything starts).
        RunError: A node could not start or the graph stalled (outputs so far are kept).
        StopRequested: SIGINT/SIGTERM; the graph is stopped and the outputs written first.
    """
    # Looked up now, not at import: while a progress bar is drawn, sys.stdout is the bar's
    # proxy, which prints above the bar.
    log = sys.stdout if log is None else log
    if opt.params_file is not None:
        check_params_file(opt.params_file)
    world_path = opt.world.resolve()
    world = load_world(world_path)
    out = opt.out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    memory = (opt.memory or out / "memory.pt").resolve()
    qtable = (opt.qtable or out / "qtable.json").resolve()
    check_files(memory, qtable, opt.features)
    if opt.record is not None:
        from roger_bringup.record import check_target
        check_target(opt.record)  # an existing bag is refused before anything starts
    domain_id = opt.domain_id if opt.domain_id is not None else pick_domain_id()
    env = ros_environment(out, domain_id)
    # Resume state belongs to one run: a new run into the same folder starts afresh.
    shutil.rmtree(env[STATE_DIR_ENV], ignore_errors=True)
    Path(env[STATE_DIR_ENV]).mkdir(parents=True)
    # This process joins the graph too (the monitor): same discovery range and profile.
    for key in ("ROS_AUTOMATIC_DISCOVERY_RANGE", PROFILE_ENV, "ROS_LOG_DIR"):
        if key in env:
            os.environ.setdefault(key, env[key])
    meta = {"policy": opt.policy, "world": str(opt.world), "seed": opt.seed,
            "features": FeatureMode.parse(opt.features).value, "domain_id": domain_id}
    recorder = ResumingRecorder(out, list(world.objects), meta, memory_file=memory)
    budget = opt.budget()
    timeout = opt.timeout_s if opt.timeout_s is not None else 120.0 + 3.0 * budget
    print(f"roger run: world {opt.world} ({len(world.objects)} objects), policy {opt.policy}, "
          f"seed {opt.seed}, ROS_DOMAIN_ID={domain_id}, output {out}\n"
          f"  watch with: {watch_command(env)}", file=log, flush=True)
    foxglove_server = None
    if opt.foxglove is not None:
        # Started before the graph: a taken port stops the run before anything runs.
        from roger_bringup.foxglove_node import FoxgloveServer, serving_line
        foxglove_server = FoxgloveServer.start(opt.foxglove_host, opt.foxglove)
        print(serving_line(foxglove_server, opt.foxglove), file=log, flush=True)
    # Taken before this process joins the graph, so that the files its own participant
    # creates count as the run's (removed at the end if a killed peer left them in use).
    shm_before = shm_files()
    context = Context()
    rclpy.init(context=context, domain_id=domain_id,
               signal_handler_options=SignalHandlerOptions.NO)
    executor = SingleThreadedExecutor(context=context)
    monitor = MonitorNode(recorder, context=context)
    observers: list[Any] = [monitor]
    if opt.view is not None:
        from roger_bringup.view_node import ViewNode
        observers.append(ViewNode(opt.view.resolve(), context=context))
    if opt.record is not None:
        from roger_bringup.recorder_node import McapRecorder
        observers.append(McapRecorder(opt.record.resolve(), meta=meta, context=context))
    if foxglove_server is not None:
        from rclpy.parameter import Parameter

        from roger_bringup.foxglove_node import FoxgloveBridge
        observers.append(FoxgloveBridge(foxglove_server, context=context, parameter_overrides=[
            Parameter("use_sim_time", Parameter.Type.BOOL, True)]))
    for node in observers:
        executor.add_node(node)
    watch = HeartbeatWatch(monitor)
    if opt.hook is not None:
        opt.hook.attach(monitor)
    graph = Graph(out, env, _node_params(opt, world_path, memory, qtable, len(observers), out,
                                         world.light_direction),
                  shm_before=shm_before, external=tuple(opt.external))
    restore = install_signal_handlers()
    t0 = time.monotonic()
    progress = ProgressBar(budget, f"run {world.name}, {opt.policy}", enabled=opt.progress)
    status = "incomplete"
    try:
        graph.start()
        deadline = time.monotonic() + STARTUP_TIMEOUT_S
        # A recorded cycle proves the graph up too: on a loaded machine the node names can
        # reach this process's graph cache seconds after the nodes are talking.
        while not (monitor.graph_up() or monitor.cycles > 0):
            executor.spin_once(timeout_sec=0.1)
            _check_children(graph, restart=False, watch=watch)
            if time.monotonic() > deadline:
                raise RunError(f"the graph did not come up within {STARTUP_TIMEOUT_S:.0f} s; "
                               f"node logs are in {out / 'logs'}")
        print(f"graph up after {time.monotonic() - t0:.1f} s: "
              f"{', '.join(c.name for c in graph.children)}", file=log, flush=True)
        deadline = time.monotonic() + timeout
        done_seen: float | None = None
        last_cycles, last_progress = -1, time.monotonic()
        next_check = 0.0
        while True:
            executor.spin_once(timeout_sec=0.1)
            # One message per spin: the checks below run at most every CHECK_PERIOD_S so
            # that the monitor keeps up with a fast graph (several messages per cycle).
            if time.monotonic() < next_check and not monitor.done:
                continue
            next_check = time.monotonic() + CHECK_PERIOD_S
            _check_children(graph, restart=True, env=env, log=log, watch=watch,
                            hang_s=opt.hang_timeout_s, max_restarts=opt.max_restarts)
            if opt.hook is not None:
                opt.hook.tick(graph, monitor.cycles, watch)
            if monitor.cycles != last_cycles:
                last_cycles, last_progress = monitor.cycles, time.monotonic()
            elif time.monotonic() - last_progress > STALL_S:
                raise RunError(f"the graph stalled: no cycle for {STALL_S:.0f} s after cycle "
                               f"{monitor.cycles}; node logs are in {out / 'logs'}")
            c = recorder.counters
            progress.update(monitor.cycles, counters_info(c))
            if monitor.done:
                # The attention node ends the run: its budget, or (--until-complete) its
                # own completion rule; the ground truth has no say in it. Its last states
                # travel on another topic than the "done" and may come later (a sample
                # lost in transit is repaired only at the writer's next heartbeat, seconds
                # on a loaded machine): wait for every reported cycle to be here.
                done_seen = done_seen or time.monotonic()
                received = monitor.cycles + monitor.monitor.waiting
                if (received >= int(c.get("cycles", 0))
                        or time.monotonic() - done_seen > DONE_WAIT_S):
                    status = "complete" if recorder.complete else "done"
                    break
            if time.monotonic() > deadline:
                raise RunError(f"the run did not finish within {timeout:.0f} s "
                               f"({monitor.cycles} cycles); node logs are in {out / 'logs'}")
        # Let the observers take the last messages in flight (bounded, no bare sleep).
        flush_until = time.monotonic() + 0.5
        while time.monotonic() < flush_until:
            executor.spin_once(timeout_sec=0.05)
    except RuntimeError as exc:
        # A signal that came while rclpy converted a message surfaces as pybind11's
        # RuntimeError, not as the StopRequested its handler raised.
        stop = restore.stop_requested(exc)
        if stop is None:
            raise
        raise stop from exc
    finally:
        restore()
        killed = graph.stop()
        executor.shutdown()
        for node in observers:
            node.destroy_node()
        rclpy.try_shutdown(context=context)
        context.destroy()  # releases this process's DDS participant and its /dev/shm files
        # A killed node's port files stay in use while its peers live, and nobody removes
        # them afterwards: remove what the run left now that all its processes stopped.
        clean_shm(shm_before, [os.getpid()])
        monitor.monitor.flush(force=True)  # states still waiting for their labels
        missing = int(recorder.counters.get("cycles", 0)) - monitor.cycles
        if status in ("complete", "done") and missing > 0:
            status = f"{status}, {missing} cycles unrecorded"
        try:
            metrics = recorder.close(time.monotonic() - t0)
        except BaseException:
            progress.close()
            raise
        # The bar's last line shows what metrics.json says (the live counters can lag).
        progress.close(metrics["cycles"], counters_info(metrics))
        metrics_status = {"status": status, "killed_on_stop": killed,
                          "restarts": {c.name: c.restarts for c in graph.children if c.restarts},
                          "deaths": graph.deaths,
                          "hang_timeout_s": opt.hang_timeout_s,
                          "longest_silence_s": {n: round(s, 2) for n, s in
                                                sorted(watch.silence.longest.items())},
                          "watch_longest_stall_s": round(watch.silence.own_longest_stall, 2),
                          "duplicate_reports": recorder.duplicates}
        with open(out / "run_status.json", "w") as fh:
            json.dump(metrics_status, fh, indent=2)
    return metrics


def watch_command(env: dict[str, str]) -> str:
    """The ros2 CLI line that sees this run: its domain, discovery range, messages."""
    return (f"ROS_DOMAIN_ID={env['ROS_DOMAIN_ID']} ROS_AUTOMATIC_DISCOVERY_RANGE="
            f"{env.get('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')} AMENT_PREFIX_PATH="
            f"{sys.prefix}:$AMENT_PREFIX_PATH ros2 topic echo /roger/metrics")


def _check_children(graph: Graph, restart: bool, env: dict[str, str] | None = None,
                    log: TextIO = sys.stdout, watch: HeartbeatWatch | None = None,
                    hang_s: float | None = HANG_TIMEOUT_S,
                    max_restarts: int = MAX_RESTARTS) -> None:
    """Report a node process that died or hangs, clean what it left in /dev/shm, restart it.

    A node that exits with code 2 refused its setup (bad world file, parameter, memory
    file): restarting it would only fail again, so the run ends with its one line. Any
    other end (a callback that raised exits 70, a signal) is restarted. With ``watch``, a
    running node silent on /diagnostics for ``hang_s`` (or that never beat within
    ``STARTUP_TIMEOUT_S`` of its start) is killed and restarted the same way.
    """
    if watch is not None:
        watch.silence.tick()
    for child in graph.dead():
        code = child.proc.returncode if child.proc is not None else None
        reason = child.exit_reason()
        if code == SETUP_EXIT:
            tail = child.log_tail(1) or reason
            raise RunError(f"node {child.name} refused to start: {tail}")
        if not restart or child.restarts >= max_restarts:
            raise RunError(f"node {child.name} died ({reason}) and was restarted "
                           f"{child.restarts} times already:\n{child.log_tail()}")
        removed = graph.restart(child)
        print(f"node {child.name} died ({reason}); removed {len(removed)} files it left in "
              f"/dev/shm; restarted it ({child.restarts}/{max_restarts})", file=log,
              flush=True)
    if watch is None or hang_s is None or not restart:
        return
    for child in graph.children:
        if child.proc is None or not child.alive():
            continue
        silent = watch.silent_for(child.proc.pid)
        if silent is not None and silent > hang_s:
            reason = f"unresponsive for {silent:.0f} s"
        elif silent is None and time.monotonic() - child.started_at > STARTUP_TIMEOUT_S:
            reason = f"unresponsive: no heartbeat {STARTUP_TIMEOUT_S:.0f} s after its start"
        else:
            continue
        if child.restarts >= max_restarts:
            raise RunError(f"node {child.name} {reason} and was restarted {child.restarts} "
                           f"times already:\n{child.log_tail()}")
        pid = child.proc.pid
        removed = graph.restart(child, reason)
        watch.forget(pid)
        print(f"node {child.name} {reason} (no heartbeat on /diagnostics); killed it; "
              f"removed {len(removed)} files it left in /dev/shm; restarted it "
              f"({child.restarts}/{max_restarts})", file=log, flush=True)


__all__ = ["RunError", "RunHook", "RunOptions", "StopRequested", "run_graph"]
