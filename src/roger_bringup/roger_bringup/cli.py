"""The ``roger`` command: ``roger run``, ``roger demo`` and friends."""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from roger_attention.config import ALPHA_SCHEDULES
from roger_common.errors import RogerError

if TYPE_CHECKING:
    from roger_experiments.ray_runner import RayRunner
    from roger_experiments.runners import RunFn, Runner, RunSpec
    from roger_experiments.sweep import SweepSpec
    from roger_experiments.train import RandomWorlds

#: Default world of the demo.
DEFAULT_WORLD = "worlds/table1.yaml"


def world_arg(text: str) -> Path:
    """A --world value: the path as given when it exists (or is absolute); a relative one
    not found from here is looked up where roger_sim keeps the shipped worlds, as the
    simulator node does (``roger_sim.world.resolve_world``): ``roger run`` with the default
    world works from any directory."""
    path = Path(text)
    if path.is_absolute() or path.exists():
        return path
    from roger_sim.world import resolve_world

    return resolve_world(text)
#: World of ``make demo``: enough regions that 204 cycles do not run out of things to see.
DEMO_WORLD = Path("worlds/inspection.yaml")


def _add_features_arg(p: argparse.ArgumentParser) -> None:
    from roger_common.types import DEFAULT_FEATURE_MODE, FeatureMode
    p.add_argument("--features", choices=[m.value for m in FeatureMode],
                   default=DEFAULT_FEATURE_MODE.value,
                   help="feature mode of perception and memory: paper (the eleven features "
                        "of equations 1-5) or extended (those plus shape from stereo and "
                        "touch, docs/perception.md); default %(default)s")


def _add_workers_args(p: argparse.ArgumentParser, default: int, always_ray: bool = False
                      ) -> None:
    p.add_argument("--workers", type=int, default=default, metavar="N",
                   help="runs in parallel at most, every run a Ray task (0: as many as Ray "
                        "has CPUs); default %(default)s" if always_ray else
                        "runs in parallel at most, as Ray tasks (1 without --address: one "
                        "after another in this process; 0: as many as Ray has CPUs); "
                        "default %(default)s")
    p.add_argument("--address", default=None, metavar="ADDR",
                   help="join the Ray cluster at ADDR (default $RAY_ADDRESS, else an "
                        "embedded local Ray on this machine's cores, loopback only)")


def _add_run_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--world", type=world_arg, default=DEFAULT_WORLD, help="world file (YAML)")
    p.add_argument("--policy", choices=("straightforward", "qlearning"),
                   default="straightforward", help="attention policy (paper, section 4)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--cycles", type=int, default=None, help="control cycles to run (default 60)")
    g.add_argument("--until-complete", action="store_true",
                   help="run until the robot itself has stored no new object for "
                        "--stable-cycles cycles and has no unmapped entry left (at most "
                        "2000 cycles); whether every object was visited is judged afterwards")
    p.add_argument("--stable-cycles", type=int, default=40,
                   help="with --until-complete: cycles without a new object that end the run")
    p.add_argument("--seed", type=int, default=0, help="seed of every random choice")
    p.add_argument("--out", type=Path, default=None, help="output folder (default runs/<policy>)")
    p.add_argument("--qtable", type=Path, default=None,
                   help="Q-table file (default OUT/qtable.json); loaded if it exists")
    p.add_argument("--memory", type=Path, default=None,
                   help="long-term memory file (default OUT/memory.pt); loaded if it exists")
    p.add_argument("--no-learn", action="store_true",
                   help="run the Q-table without updating it")
    _add_features_arg(p)
    p.add_argument("--params-file", type=Path, default=None, metavar="FILE",
                   help="a standard ROS 2 parameters file handed to every node (e.g. a copy "
                        "of docs/params_example.yaml); roger run's own options (world, "
                        "policy, seed, cycles, files) and the flags below win over it")
    p.add_argument("--image-size", type=int, default=None,
                   help="retina size in pixels (default: the params file's, else 128)")
    p.add_argument("--realtime", action="store_true", help="pace the simulated clock to wall time")
    p.add_argument("--gui", action="store_true", help="open pybullet's window (needs a display)")
    p.add_argument("--domain-id", type=int, default=None,
                   help="ROS_DOMAIN_ID (default: $ROS_DOMAIN_ID or a random one, printed)")
    p.add_argument("--timeout", type=float, default=None, help="wall-clock limit in seconds")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--view", type=Path, default=None,
                   help="write the attention view (PNG frames and view.gif) to this folder")
    p.add_argument("--record", type=Path, default=None, metavar="BAG",
                   help="record every topic to a rosbag2 bag: a new folder BAG holding "
                        "metadata.yaml and BAG_0.mcap (as ros2 bag record -s mcap -o BAG), "
                        "or, for a name ending in .mcap, that one MCAP file")
    p.add_argument("--foxglove", type=int, nargs="?", const=8765, default=None,
                   metavar="PORT",
                   help="serve every topic live to Foxglove on a WebSocket server at PORT "
                        "(default 8765; 0: a free port, printed): connect Foxglove to "
                        "ws://127.0.0.1:PORT and load docs/foxglove-layout.json")
    p.add_argument("--foxglove-host", default=None, metavar="ADDR",
                   help="with --foxglove: the address it listens on (default 127.0.0.1, "
                        "this machine only; the server has no authentication)")


def _run_options(args: argparse.Namespace):  # type: ignore[no-untyped-def]
    from roger_bringup.run import RunOptions
    cycles = None if args.until_complete else (args.cycles or 60)
    return RunOptions(
        world=args.world, out=args.out or Path("runs") / args.policy, policy=args.policy,
        cycles=cycles, until_complete=args.until_complete, stable_cycles=args.stable_cycles,
        seed=args.seed, qtable=args.qtable, memory=args.memory, learn=not args.no_learn,
        features=args.features,
        image_size=args.image_size, realtime=args.realtime or None, gui=args.gui or None,
        params_file=args.params_file,
        domain_id=args.domain_id, timeout_s=args.timeout, progress=not args.quiet,
        view=args.view, record=args.record, **_foxglove_options(args))


def _foxglove_options(args: argparse.Namespace) -> dict:
    """``--foxglove [PORT]`` and ``--foxglove-host ADDR`` as RunOptions fields."""
    from roger_common.errors import ConfigError
    if args.foxglove is None:
        if args.foxglove_host is not None:
            raise ConfigError("--foxglove-host needs --foxglove [PORT]")
        return {}
    return {"foxglove": args.foxglove, "foxglove_host": args.foxglove_host or "127.0.0.1"}


def cmd_run(args: argparse.Namespace) -> int:
    """``roger run``: one run of the graph; prints the metrics."""
    from roger_bringup.run import run_graph
    metrics = run_graph(_run_options(args))
    print(json.dumps(metrics, indent=2))
    if args.until_complete:
        how = ("the robot's own completion rule" if metrics.get("complete")
               else "the cycle budget (the robot never judged it complete)")
        print(f"stopped after {metrics['cycles']} cycles by {how}; every object visited "
              f"(ground truth, judged afterwards): "
              f"{'yes' if metrics.get('every_object_visited') else 'no'} "
              f"({metrics['objects_visited']}/{metrics['objects_in_world']})")
    return 0


def cmd_chaos(args: argparse.Namespace) -> int:
    """``roger chaos``: one long run with seeded faults, checked; writes DIR/chaos.json."""
    from roger_bringup.chaos import CHAOS_FILE, ChaosOptions, run_chaos
    result = run_chaos(ChaosOptions(world=args.world, cycles=args.cycles, faults=args.faults,
                                    seed=args.seed, out=args.out, policy=args.policy,
                                    domain_id=args.domain_id))
    print(json.dumps({k: v for k, v in result.items() if k != "lost_store_details"},
                     indent=2))
    if not result["ok"]:
        for line in result["failed"]:
            print(f"roger chaos: check failed: {line}", file=sys.stderr)
        print(f"roger chaos: {len(result['failed'])} checks failed; see "
              f"{args.out / CHAOS_FILE}", file=sys.stderr)
        return 1
    print(f"roger chaos: every check passed; {args.out / CHAOS_FILE}", file=sys.stderr)
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    """``roger bench``: graph vs core, cycle vs floor, scaling; writes DIR/bench.json."""
    from roger_bringup.bench import main_bench
    result = main_bench(args.out, quick=args.quick, progress=not args.quiet)
    print(f"bench.json: {args.out / 'bench.json'}")
    return 0 if result else 1


def cmd_replay(args: argparse.Namespace) -> int:
    """``roger replay``: regenerate cycles.csv, metrics.json and figures from a recording."""
    from roger_bringup.record import replay
    print(json.dumps(replay(args.file, args.out), indent=2))
    return 0


def _train(worlds: list[Path] | None, spec: RandomWorlds | None, seeds: list[int],
           cycles: int, out: Path, graph: bool, quiet: bool, features: str,
           alpha_schedule: str = "constant") -> dict:
    """Q-learning over the world files and the random worlds of ``spec``, every one with
    every seed, into ``out`` (in process unless ``graph``)."""
    from roger_experiments.train import RandomWorlds, train_in_process

    if not graph:
        return train_in_process(spec or RandomWorlds(count=0), seeds, cycles, out,
                                progress=not quiet, features=features, files=worlds,
                                alpha_schedule=alpha_schedule)
    from roger_bringup.run import RunOptions, run_graph
    from roger_experiments.train import describe_random, fresh_table, train, write_worlds

    files = list(worlds or [])
    made: dict = {"files": [str(w) for w in files]}
    if spec is not None:
        files += write_worlds(spec.worlds(), out / "worlds")
        made["random"] = describe_random(spec)

    def run_one(world: Path, seed: int, qtable: Path, run_dir: Path) -> dict:
        return run_graph(RunOptions(world=world, out=run_dir, policy="qlearning",
                                    cycles=cycles, seed=seed, qtable=qtable,
                                    features=features, progress=not quiet))
    fresh_table(out, alpha_schedule)
    return train(files, seeds, out, run_one, progress=not quiet, describe=made)


def _runner(args: argparse.Namespace, graph: bool) -> tuple[Runner, bool]:
    """The runner of a compare or demo: one run after another in this process with
    ``--workers 1`` and no ``--address``, else Ray tasks (embedded Ray, or the cluster).
    Returns it and whether Ray was started (``stop_ray`` when done)."""
    from roger_experiments.runners import SequentialRunner, run_in_process

    run: RunFn = run_in_process
    if graph:
        from roger_bringup.graph_run import run_spec_graph, run_spec_graph_quiet
        run = run_spec_graph_quiet
    workers = args.workers if args.workers and args.workers > 0 else None
    address = getattr(args, "address", None)
    if workers == 1 and not address:
        if graph:
            def run_loud(spec: RunSpec, out: Path) -> dict:
                return run_spec_graph(spec, out, progress=not args.quiet)
            run = run_loud
        return SequentialRunner(run), False
    from roger_experiments.ray_runner import RayRunner, code_version, start_ray
    start_ray(address, workers)
    domains = _domains() if graph else ()
    return RayRunner(run, workers=workers, domains=domains,
                     expect_version=code_version()), True


def _domains() -> tuple[int, ...]:
    """The ROS domain ids a parallel runner hands its graph runs, one per run in flight,
    so that no two runs on one host share one (``graph_run.free_domains``)."""
    from roger_bringup.graph_run import free_domains
    return free_domains()


def cmd_compare(args: argparse.Namespace) -> int:
    """``roger compare``: both policies, same world and seeds; Table 2 and Figures 4-6.

    The Q-learning policy runs a trained Q-table, greedy and frozen: ``--qtable FILE``, or
    one ``roger train`` learns first (in process) on random worlds other than this one.
    The experiment itself is ``roger_experiments.table2.run_table2``.
    """
    from roger_experiments.table2 import Table2Spec, run_table2
    from roger_experiments.train import RandomWorlds

    if args.qtable is not None:
        from roger_attention.qlearning import QTable
        QTable.load(args.qtable)  # a missing or corrupt table is refused before any run
    spec = Table2Spec(
        world=args.world, seeds=tuple(range(args.seed0, args.seed0 + args.seeds)),
        cycles=args.cycles, features=args.features,
        also_modes=tuple(getattr(args, "also_modes", None) or ()),
        stable_cycles=args.stable_cycles, qtable=args.qtable,
        training=RandomWorlds(count=args.train_worlds), train_seeds=args.train_seeds)
    runner, started = _runner(args, graph=not args.in_process)
    try:
        results = run_table2(spec, args.out, runner, progress=not args.quiet)
    finally:
        if started:
            from roger_experiments.ray_runner import stop_ray
            stop_ray()
    for mode in spec.modes():
        out = args.out if mode == args.features else args.out / mode
        trained = results[mode]["trained"]
        if mode == args.features and trained.world_seen:
            print(f"roger compare: warning: {args.world} is one of the worlds "
                  f"{trained.qtable} was trained on", file=sys.stderr)
        if len(spec.modes()) > 1:
            print(f"\nfeature mode {mode} -> {out}")
        print()
        print((out / "table2.md").read_text())
        print(f"Q-learning policy: {trained.qtable}, {trained.origin}, greedy and frozen")
        for c in results[mode]["claims"]:
            print(f"  {c['verdict']:>26}: {c['claim']} ({c['holds_in']}/{c['seeds']} seeds)")
        c = results[mode]["completion"]
        if c is not None:
            print(f"  {c['verdict']:>26}: {c['claim']} ({c['every_object_visited']}/"
                  f"{c['runs']} runs; the robot's rule ended {c['complete']}/{c['runs']})")
    if len(spec.modes()) > 1:
        print((args.out / "modes.md").read_text())
    print(f"\nfigures: {args.out / 'fig4.png'}, {args.out / 'fig5.png'}, "
          f"{args.out / 'fig6.png'}; report: {args.out / 'report.md'}")
    return 0


def cmd_sweep(args: argparse.Namespace) -> int:
    """``roger sweep``: Table 2 over worlds x seeds x policies x feature modes x step-size
    schedules x training draws, every run a Ray task; resumes from the cells already in
    DIR."""
    from roger_experiments.ray_runner import code_version, start_ray, stop_ray
    from roger_experiments.sweep import load_spec, run_sweep, train_scheduled

    spec = load_spec(args.spec)
    if args.report_only:
        return _sweep_report_only(args, spec)
    version = code_version()
    start_ray(args.address, args.workers if args.workers and args.workers > 0 else None)
    try:
        runner = _sweep_runner(args, spec.mode == "graph", spec.timeout_s, version)
        trainer = replace(runner, run=train_scheduled, domains=(), timeout_s=None)
        result = run_sweep(spec, args.out, runner, trainer, version, progress=not args.quiet,
                           in_flight=lambda: runner.in_flight + trainer.in_flight)
    except KeyboardInterrupt:
        print(f"roger sweep: stopped; the finished runs are in {args.out / 'cells'}, and "
              "the same command again does the rest", file=sys.stderr)
        return 130
    finally:
        stop_ray()
    return _print_sweep(args, result)


def _sweep_report_only(args: argparse.Namespace, spec: SweepSpec) -> int:
    """``roger sweep --report-only``: the report of the runs already in DIR."""
    from roger_experiments.ray_runner import code_version
    from roger_experiments.sweep import report_from_disk, versions_on_disk

    found = versions_on_disk(args.out)
    version = args.code_version or (found[0] if len(found) == 1 else None)
    if version is None:
        why = (f"{args.out} holds runs of code versions {', '.join(found)}; name one with "
               "--code-version" if found else f"{args.out} holds no runs")
        print(f"roger sweep: {why}", file=sys.stderr)
        return 2
    if version != code_version():
        print(f"roger sweep: reporting the runs of code version {version} (this code is "
              f"{code_version()})", file=sys.stderr)
    result = report_from_disk(spec, args.out, version)
    return _print_sweep(args, result)


def _print_sweep(args: argparse.Namespace, result: dict[str, Any]) -> int:
    """The sweep's summary on stdout; exit 1 if a run failed."""
    print(f"{result['done']} of {result['cells']} runs done, {result['failed']} failed")
    for c in result["claims"]:
        lo, hi = c["ci95"]
        print(f"  {c['features']:>8} {c['alpha_schedule']:>8} {c['budget']:>5} "
              f"{c['verdict']:>13}: {c['claim']} "
              f"(mean {c['mean_difference']:+.2f} [{lo:+.2f}, {hi:+.2f}], Wilcoxon p "
              f"{c['wilcoxon_p']:.3g}, {c['pairs']} pairs)")
    print(f"runs: {args.out / 'runs.csv'}; report: {args.out / 'report.md'}")
    return 0 if result["failed"] == 0 else 1


def _sweep_runner(args: argparse.Namespace, graph: bool, timeout_s: float | None,
                  version: str) -> RayRunner:
    """The Ray runner of a sweep (keeps going past failed runs)."""
    from roger_experiments.ray_runner import RayRunner
    from roger_experiments.runners import run_in_process

    run: RunFn = run_in_process
    if graph:
        from roger_bringup.graph_run import run_spec_graph_quiet
        run = run_spec_graph_quiet
    domains = _domains() if graph else ()
    return RayRunner(run, workers=args.workers if args.workers and args.workers > 0 else None,
                     keep_going=True, timeout_s=timeout_s, domains=domains,
                     expect_version=version)


def cmd_train(args: argparse.Namespace) -> int:
    """``roger train``: Q-learning over worlds and seeds; writes the Q-table and Figure 6."""
    from roger_experiments.train import RandomWorlds

    count = args.random_worlds
    if count is None:
        count = 0 if args.worlds else RandomWorlds().count
    spec = RandomWorlds(count=count, seed0=args.world_seed0) if count > 0 else None
    if not args.worlds and spec is None:
        raise RogerError("roger train: no training world (give --worlds or --random-worlds)")
    seeds = list(range(args.seed0, args.seed0 + args.seeds))
    summary = _train(args.worlds, spec, seeds, args.cycles, args.out, args.graph, args.quiet,
                     args.features, args.alpha_schedule)
    print(json.dumps({k: v for k, v in summary.items() if k not in ("q", "worlds")},
                     indent=2))
    print(f"Q-table: {args.out / 'qtable.json'}; Figure 6: {args.out / 'td_errors.png'}; "
          f"summary: {args.out / 'train.json'}")
    return 0


def cmd_features(args: argparse.Namespace) -> int:
    """``roger features``: do the features of one object repeat across the robot's looks?"""
    from roger_experiments import feature_report
    from roger_memory.config import MemoryConfig
    from roger_perception.config import PerceptionConfig
    from roger_sim.world import load_world

    result = feature_report.write(
        feature_report.collect_looks(load_world(args.world), seed=args.seed,
                                     perception_config=PerceptionConfig(features=args.features),
                                     noise_looks=args.noise_looks), args.out,
        memory_config=MemoryConfig.for_mode(args.features))
    print(feature_report.markdown(result))
    print(f"written: {args.out / 'features.md'}, features.json, features.png, looks.csv")
    return 0


def cmd_table1(args: argparse.Namespace) -> int:
    """``roger table1``: the paper's Table 1 as Roger perceives the four boxes."""
    from roger_experiments import table1
    from roger_sim.world import load_world

    result = table1.write(load_world(args.world), args.out, seed=args.seed)
    print(table1.markdown(result))
    print(f"written: {args.out / 'table1.md'}, {args.out / 'table1.json'}")
    return 0


def main(argv: list[str] | None = None) -> None:
    """Entry point of ``roger``."""
    parser = argparse.ArgumentParser(prog="roger", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    p_run = sub.add_parser("run", help="run the multi-process graph once")
    _add_run_args(p_run)
    p_run.set_defaults(func=cmd_run)
    for name, help_text, world, cycles, seeds, out in (
            ("compare", "both policies on the same world and seeds: Table 2, Figures 4-6",
             world_arg(DEFAULT_WORLD), 204, 3, Path("runs/compare")),
            ("demo", "the main job of make demo: roger compare on the default world",
             DEMO_WORLD, 204, 5, Path("runs/demo"))):
        p_cmp = sub.add_parser(name, help=help_text)
        p_cmp.add_argument("--world", type=Path, default=world, help="world file (YAML)")
        p_cmp.add_argument("--cycles", type=int, default=cycles, help="control cycles per run")
        p_cmp.add_argument("--seeds", type=int, default=seeds, help="number of seeds")
        p_cmp.add_argument("--seed0", type=int, default=0, help="first seed")
        p_cmp.add_argument("--out", type=Path, default=out, help="output folder")
        p_cmp.add_argument("--in-process", action="store_true",
                           help="run the same core loop without ROS (faster, no graph)")
        p_cmp.add_argument("--qtable", type=Path, default=None,
                           help="trained Q-table for the Q-learning policy (run greedy, "
                                "frozen); default: roger train first, into OUT/train")
        p_cmp.add_argument("--train-worlds", type=int, default=4,
                           help="without --qtable: random training worlds")
        p_cmp.add_argument("--train-seeds", type=int, default=2,
                           help="without --qtable: training seeds per world")
        p_cmp.add_argument("--stable-cycles", type=int, default=40,
                           help="also run each policy and seed until the robot's own "
                                "completion rule (no new object for this many cycles, no "
                                "unmapped entry; at most 2000 cycles) for the report's "
                                "'every object visited'; 0 skips those runs")
        p_cmp.add_argument("--quiet", action="store_true", help="no progress bars")
        _add_workers_args(p_cmp, default=1)
        _add_features_arg(p_cmp)
        p_cmp.add_argument("--also-modes", nargs="*", default=(
            ["paper"] if name == "demo" else []), choices=("paper", "extended"),
            metavar="MODE",
            help="also run these feature modes (same seeds and Q-table) into OUT/MODE and "
                 "put Table 2 and the claims side by side in OUT/modes.md and report.md "
                 "(default: paper for demo, none for compare)")
        p_cmp.set_defaults(func=cmd_compare)
    p_sweep = sub.add_parser("sweep", help="Table 2 over worlds x seeds x policies x feature "
                             "modes x training draws, on Ray; resumable")
    p_sweep.add_argument("spec", type=Path, metavar="SPEC.yaml",
                         help="the sweep (docs/experiments.md, e.g. sweeps/claims.yaml)")
    p_sweep.add_argument("--out", type=Path, required=True, metavar="DIR",
                         help="output folder; a sweep run again into it does only the runs "
                              "not finished there")
    p_sweep.add_argument("--quiet", action="store_true", help="no progress bar")
    p_sweep.add_argument("--report-only", action="store_true",
                         help="run nothing: write the report of the runs already in DIR "
                              "(those of one code version, see --code-version)")
    p_sweep.add_argument("--code-version", metavar="V",
                         help="with --report-only: the code version whose runs to report "
                              "(needed when DIR holds several)")
    _add_workers_args(p_sweep, default=0, always_ray=True)
    p_sweep.set_defaults(func=cmd_sweep)
    p_chaos = sub.add_parser("chaos", help="one long run with seeded faults (SIGKILL, SIGTERM, "
                             "SIGSTOP of random nodes), checked (docs/reliability.md)")
    p_chaos.add_argument("--world", type=Path, default=DEMO_WORLD, help="world file (YAML)")
    p_chaos.add_argument("--cycles", type=int, default=1000, help="control cycles to run")
    p_chaos.add_argument("--faults", type=int, default=50, help="faults to inject")
    p_chaos.add_argument("--seed", type=int, default=1,
                         help="seed of the fault schedule and of the run")
    p_chaos.add_argument("--out", type=Path, default=Path("runs/chaos"),
                         help="output folder (an earlier run's files there are replaced)")
    p_chaos.add_argument("--policy", choices=("straightforward", "qlearning"),
                         default="qlearning", help="attention policy; default %(default)s")
    p_chaos.add_argument("--domain-id", type=int, default=None,
                         help="ROS_DOMAIN_ID (default: $ROS_DOMAIN_ID or a random one)")
    p_chaos.set_defaults(func=cmd_chaos)
    p_bench = sub.add_parser("bench", help="performance ratios of the graph (docs/performance.md)")
    p_bench.add_argument("--out", type=Path, default=Path("runs/bench"), help="output folder")
    p_bench.add_argument("--quick", action="store_true", help="a few cycles only (smoke test)")
    p_bench.add_argument("--quiet", action="store_true", help="no progress bar")
    p_bench.set_defaults(func=cmd_bench)
    p_replay = sub.add_parser("replay", help="regenerate metrics and figures from a recording")
    p_replay.add_argument("file", type=Path, metavar="BAG",
                          help="bag folder or .mcap file written by roger run --record")
    p_replay.add_argument("--out", type=Path, default=Path("runs/replay"), help="output folder")
    p_replay.set_defaults(func=cmd_replay)
    p_train = sub.add_parser("train", help="train the Q-learning policy over worlds and seeds")
    p_train.add_argument("--worlds", type=Path, nargs="+", default=None,
                         help="world files to train on, in order (default: random worlds)")
    p_train.add_argument("--random-worlds", type=int, default=None, metavar="N",
                         help="also train on N random worlds of the demo world's kind "
                              "(roger_sim.worldgen; default 4 without --worlds, else 0)")
    p_train.add_argument("--world-seed0", type=int, default=100,
                         help="seed of the first random world (the next ones follow)")
    p_train.add_argument("--seeds", type=int, default=2, help="seeds per world")
    p_train.add_argument("--seed0", type=int, default=0, help="first seed")
    p_train.add_argument("--cycles", type=int, default=204, help="control cycles per run")
    p_train.add_argument("--out", type=Path, default=Path("runs/train"), help="output folder")
    p_train.add_argument("--alpha-schedule", choices=ALPHA_SCHEDULES, default="constant",
                         help="step size of the Q-updates: constant (the paper's alpha 0.5) "
                              "or visits (alpha / (1 + n(s,a) / alpha_k), settles; "
                              "docs/attention.md)")
    p_train.add_argument("--graph", action="store_true",
                         help="train through the multi-process graph instead of in process")
    p_train.add_argument("--quiet", action="store_true", help="no progress bars")
    _add_features_arg(p_train)
    p_train.set_defaults(func=cmd_train)
    p_feat = sub.add_parser("features", help="do the features repeat? within- vs "
                            "between-category spread of every feature, ROI purity")
    p_feat.add_argument("--world", type=Path, default=DEMO_WORLD, help="world file (YAML)")
    p_feat.add_argument("--seed", type=int, default=0, help="seed of the sensor noise")
    p_feat.add_argument("--out", type=Path, default=Path("runs/features"),
                        help="output folder")
    p_feat.add_argument("--noise-looks", type=int, default=3,
                        help="looks at each place at the end, one fixation with fresh pixel "
                        "noise: the sensor-noise spread and each feature's ceiling (0: none)")
    _add_features_arg(p_feat)
    p_feat.set_defaults(func=cmd_features)
    p_t1 = sub.add_parser("table1", help="the paper's Table 1: the four boxes' perceived I, D, W")
    p_t1.add_argument("--world", type=world_arg, default=DEFAULT_WORLD, help="world file (YAML)")
    p_t1.add_argument("--seed", type=int, default=0, help="seed of the sensor noise")
    p_t1.add_argument("--out", type=Path, default=Path("runs/table1"), help="output folder")
    p_t1.set_defaults(func=cmd_table1)
    args = parser.parse_args(argv)
    from roger_bringup.orchestrator import StopRequested
    try:
        sys.exit(args.func(args))
    except StopRequested as exc:
        print(f"roger: stopped by {exc}; every node was shut down, outputs kept",
              file=sys.stderr)
        sys.exit(130)
    except RogerError as exc:
        print(f"roger: {exc}", file=sys.stderr)
        sys.exit(2)


if __name__ == "__main__":
    main()
