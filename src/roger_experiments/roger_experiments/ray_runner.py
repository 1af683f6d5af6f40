"""Runs as Ray tasks: the parallel runner of ``roger demo``, ``roger compare --workers`` and
``roger sweep`` (Ray Core, pinned in requirements.txt).

Every run is a ``@ray.remote`` task that runs its ``RunSpec`` in a scratch folder of the
worker and returns plain data: its metrics and the bytes of every file it wrote. Only the
driver writes the output folder, each run's folder atomically (a scratch folder beside it,
then one rename), so worker machines need no shared filesystem and a killed driver leaves
only whole runs behind.

The embedded local Ray (no ``address``) listens on loopback only: ``start_ray`` sets
``RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0`` before Ray is imported, which makes Ray take
127.0.0.1 as the node's address, and then gcs_server, the raylet, the workers, the
driver and the runtime-env agent all bind 127.0.0.1 (measured with Ray 2.60.0,
test/test_sweep.py). The dashboard stays off; token authentication stays as Ray sets it.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import socket
import time
import traceback
import uuid
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from roger_experiments.runners import Job, RunFn, RunSpec, scratch_dir
from roger_experiments.train import TrainDraw

#: Ray's switch for single-machine (loopback) mode, read when Ray is imported.
LOOPBACK_ENV = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"
#: The packages whose source makes the code version (``code_version``).
PACKAGES: tuple[str, ...] = ("roger_common", "roger_sim", "roger_perception",
                             "roger_memory", "roger_attention", "roger_experiments",
                             "roger_bringup")
#: Environment variable of a graph run's leased ROS domain id (roger_bringup.graph_run).
DOMAIN_ENV = "ROGER_LEASED_DOMAIN_ID"
#: What the driver adds to each run's folder: the worker's host, code version, seconds.
WORKER_FILE = "worker.json"
#: Times Ray reruns a task whose worker process died (not one that raised).
MAX_RETRIES = 2


class RunFailed(Exception):
    """A run raised (or timed out) on its worker; the message holds its traceback, and
    ``files`` what the run had written by then."""

    def __init__(self, message: str, files: dict[str, bytes] | None = None) -> None:
        super().__init__(message)
        self.files = files or {}


def code_version() -> str:
    """A digest of the source of the Roger packages (their .py, .xml and .yaml files) as
    installed where this runs: equal digests, equal code."""
    import importlib.util

    h = hashlib.sha256()
    for name in PACKAGES:
        spec = importlib.util.find_spec(name)
        if spec is None or spec.origin is None:
            continue
        root = Path(spec.origin).parent
        for path in sorted(p for p in root.rglob("*")
                           if p.suffix in (".py", ".xml", ".yaml")
                           and "__pycache__" not in p.parts):
            h.update(f"{name}/{path.relative_to(root)}\0".encode())
            h.update(path.read_bytes())
    return h.hexdigest()[:16]


def start_ray(address: str | None = None, workers: int | None = None,
              temp_dir: Path | None = None) -> None:
    """Join the Ray cluster at ``address`` (or ``RAY_ADDRESS``), or start an embedded local
    Ray on this machine's cores (``workers`` of them at most), listening on loopback only,
    without the dashboard. Call ``stop_ray`` when done."""
    address = address or os.environ.get("RAY_ADDRESS") or None
    if address is None:
        # Must be set before Ray is imported (ray._private.ray_constants reads it then).
        os.environ.setdefault(LOOPBACK_ENV, "0")
    import ray

    if ray.is_initialized():
        return
    kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False,
                              "configure_logging": True, "logging_level": "warning"}
    if address is None:
        kwargs["num_cpus"] = workers or os.cpu_count() or 1
        if temp_dir is not None:
            kwargs["_temp_dir"] = str(temp_dir)
        ray.init(**kwargs)
    else:
        ray.init(address=address, **kwargs)


def stop_ray() -> None:
    """Disconnect; an embedded Ray stops every process it started."""
    import ray

    ray.shutdown()


def run_task(run: Callable[[Any, Path], dict[str, Any]], spec: RunSpec | TrainDraw,
             env: dict[str, str] | None = None) -> dict[str, Any]:
    """What a Ray task runs: ``run(spec, scratch)`` in a scratch folder of the worker, then
    the folder's files as bytes. An exception comes back as its traceback (the run failed,
    the sweep goes on); only a dead worker makes Ray retry."""
    scratch = scratch_dir("roger-run-")
    out = scratch / "run"
    saved = {k: os.environ.get(k) for k in (env or {})}
    os.environ.update(env or {})
    t0 = time.monotonic()
    started = time.time()
    error = None
    metrics: dict[str, Any] | None = None
    try:
        metrics = run(spec, out)
    except Exception:  # noqa: BLE001 - every failure of a run is recorded, none is lost
        error = traceback.format_exc()
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    files = {str(p.relative_to(out)): p.read_bytes()
             for p in sorted(out.rglob("*")) if p.is_file()} if out.exists() else {}
    shutil.rmtree(scratch, ignore_errors=True)
    return {"metrics": metrics, "error": error, "files": files, "host": socket.gethostname(),
            "node": _node_id(), "code_version": code_version(), "started": started,
            "seconds": time.monotonic() - t0}


def _node_id() -> str:
    """The Ray node this runs on ("" outside Ray)."""
    import ray

    return str(ray.get_runtime_context().get_node_id()) if ray.is_initialized() else ""


def write_run_files(out: Path, files: dict[str, bytes]) -> None:
    """Put a run's files into ``out`` at once: written into a scratch folder beside it,
    then renamed (an older ``out`` is replaced)."""
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.parent / f".{out.name}.tmp-{uuid.uuid4().hex[:8]}"
    for rel, data in files.items():
        path = tmp / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data)
    tmp.mkdir(parents=True, exist_ok=True)
    if out.exists():
        old = out.parent / f".{out.name}.old-{uuid.uuid4().hex[:8]}"
        out.rename(old)
        tmp.rename(out)
        shutil.rmtree(old, ignore_errors=True)
    else:
        tmp.rename(out)


@dataclass
class RayRunner:
    """Runs jobs as Ray tasks, at most ``workers`` at once (None: as many as Ray has CPUs),
    and writes each finished run's files into its job's folder from the driver.

    Attributes:
        run: What a task runs (``runners.run_in_process`` or the graph's
            ``roger_bringup.graph_run.run_spec_graph_quiet``).
        workers: Most runs in flight.
        keep_going: Yield a failed run's exception instead of raising it.
        timeout_s: Wall seconds after which a run is cancelled and recorded as failed.
        domains: For graph runs: ROS domain ids handed out so that no two runs in flight
            share one (``roger_bringup.graph_run.DOMAIN_ENV``); empty for in-process runs.
        expect_version: The driver's code version; a worker running other code fails its
            runs (its results would not belong to this code).
    """

    run: RunFn | Callable[[TrainDraw, Path], dict[str, Any]]
    workers: int | None = None
    keep_going: bool = False
    timeout_s: float | None = None
    domains: tuple[int, ...] = ()
    expect_version: str | None = None
    #: Where each finished job's task ran (host name), for the records.
    hosts: dict[Path, str] = field(default_factory=dict)
    #: Runs in flight now (for a progress line).
    in_flight: int = 0

    def __call__(self, jobs: Sequence[Job]) -> Iterator[tuple[Job, dict[str, Any] | Exception]]:
        import ray

        task = ray.remote(num_cpus=1, max_retries=MAX_RETRIES)(run_task)
        cap = self.workers or max(1, int(ray.cluster_resources().get("CPU", 1)))
        if self.domains:
            cap = min(cap, len(self.domains))
        free = list(self.domains)
        self.in_flight = 0
        pending = list(jobs)
        flying: dict[Any, tuple[Job, float, int | None]] = {}
        try:
            while pending or flying:
                while pending and len(flying) < cap:
                    job = pending.pop(0)
                    domain = free.pop(0) if free else None
                    env = {} if domain is None else {DOMAIN_ENV: str(domain)}
                    ref = task.remote(self.run, job.spec, env)
                    flying[ref] = (job, time.monotonic(), domain)
                self.in_flight = len(flying)
                ready, _ = ray.wait(list(flying), num_returns=1, timeout=1.0)
                now = time.monotonic()
                for ref in list(flying):
                    job, t0, domain = flying[ref]
                    late = (self.timeout_s is not None and ref not in ready
                            and now - t0 > self.timeout_s)
                    if ref not in ready and not late:
                        continue
                    del flying[ref]
                    self.in_flight = len(flying)
                    if domain is not None:
                        free.append(domain)
                    result = self._finish(job, ref, late)
                    if isinstance(result, Exception) and not self.keep_going:
                        raise result
                    yield job, result
        finally:
            self.in_flight = 0
            for ref in flying:
                ray.cancel(ref, force=True)

    def _finish(self, job: Job, ref: Any, late: bool) -> dict[str, Any] | Exception:
        import ray

        if late:
            ray.cancel(ref, force=True)
            return RunFailed(f"timed out after {self.timeout_s:g} s")
        try:
            got = ray.get(ref)
        except Exception as exc:  # noqa: BLE001 - a task Ray gave up on (worker died)
            return RunFailed(f"{type(exc).__name__}: {exc}")
        self.hosts[job.out] = got["host"]
        if self.expect_version and got["code_version"] != self.expect_version \
                and got["host"] != socket.gethostname():
            return RunFailed(f"worker {got['host']} runs code {got['code_version']}, the "
                             f"driver {self.expect_version}: install the same code there")
        if got["error"] is not None:
            return RunFailed(got["error"], got["files"])
        # Where and on what code it ran: on the driver's own machine a source file edited
        # during the sweep shows here as another code version.
        worker = {"host": got["host"], "node": got["node"], "code_version": got["code_version"],
                  "started": round(got["started"], 3), "seconds": round(got["seconds"], 3)}
        write_run_files(job.out, {**got["files"], **job.extra,
                                  WORKER_FILE: (json.dumps(worker) + "\n").encode()})
        metrics: dict[str, Any] = got["metrics"]
        return metrics
