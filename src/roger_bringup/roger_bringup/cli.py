"""The ``roger`` command: ``roger run``, ``roger demo`` and friends."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from roger_common.errors import RogerError

if TYPE_CHECKING:
    from roger_common.types import WorldSpec
    from roger_experiments.compare import TrainedTable
    from roger_experiments.train import RandomWorlds

#: Default world of the demo.
DEFAULT_WORLD = Path("worlds/table1.yaml")
#: World of ``make demo``: enough regions that 204 cycles do not run out of things to see.
DEMO_WORLD = Path("worlds/inspection.yaml")
#: Most cycles a run until the robot's own completion may take.
COMPLETE_MAX = 2000


def _add_features_arg(p: argparse.ArgumentParser) -> None:
    from roger_common.types import DEFAULT_FEATURE_MODE, FeatureMode
    p.add_argument("--features", choices=[m.value for m in FeatureMode],
                   default=DEFAULT_FEATURE_MODE.value,
                   help="feature mode of perception and memory: paper (the eleven features "
                        "of equations 1-5) or extended (those plus shape from stereo and "
                        "touch, docs/perception.md); default %(default)s")


def _add_run_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--world", type=Path, default=DEFAULT_WORLD, help="world file (YAML)")
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
        view=args.view, record=args.record)


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


def _training_worlds(files: list[Path] | None, spec: RandomWorlds | None,
                     folder: Path) -> tuple[list[Path], dict]:
    """The training world files: the files given, then the random worlds of ``spec``
    written into ``folder``; and how they were made (for train.json)."""
    from roger_experiments.train import describe_random, write_worlds

    worlds = list(files or [])
    made: dict = {"files": [str(w) for w in worlds]}
    if spec is not None:
        worlds += write_worlds(spec.worlds(), folder)
        made["random"] = describe_random(spec)
    return worlds, made


def _train(worlds: list[Path], made: dict, seeds: list[int], cycles: int, out: Path,
           graph: bool, quiet: bool, features: str) -> dict:
    """Q-learning over ``worlds`` x ``seeds`` into ``out`` (in process unless ``graph``)."""
    import time

    from roger_experiments.train import train

    if graph:
        from roger_bringup.run import RunOptions, run_graph

        def run_one(world: Path, seed: int, qtable: Path, run_dir: Path) -> dict:
            return run_graph(RunOptions(world=world, out=run_dir, policy="qlearning",
                                        cycles=cycles, seed=seed, qtable=qtable,
                                        features=features, progress=not quiet))
    else:
        from roger_experiments.core_loop import run_core
        from roger_sim.world import load_world

        def run_one(world: Path, seed: int, qtable: Path, run_dir: Path) -> dict:
            t0 = time.monotonic()
            # The loop saves the Q-table it learnt to ``qtable`` when it closes.
            recorder, _ = run_core(load_world(world), "qlearning", cycles, seed=seed,
                                   out=run_dir, qtable_path=qtable, features=features)
            assert recorder is not None
            return recorder.close(time.monotonic() - t0)
    if (out / "qtable.json").exists():
        (out / "qtable.json").unlink()  # training starts from a fresh table
    return train(worlds, seeds, out, run_one, progress=not quiet, describe=made)


def cmd_compare(args: argparse.Namespace) -> int:
    """``roger compare``: both policies, same world and seeds; Table 2 and Figures 4-6.

    The Q-learning policy runs a trained Q-table, greedy and frozen: ``--qtable FILE``, or
    one ``roger train`` learns first (in process) on random worlds other than this one.
    """
    from roger_experiments.compare import TrainedTable
    from roger_experiments.train import RandomWorlds
    from roger_sim.world import load_world

    world = load_world(args.world)
    seeds = list(range(args.seed0, args.seed0 + args.seeds))
    if args.qtable is not None:
        from roger_attention.qlearning import QTable
        QTable.load(args.qtable)  # a missing or corrupt table is refused before any run
        qtable, origin = args.qtable, "given with --qtable"
    else:
        spec = RandomWorlds(count=args.train_worlds)
        train_out = args.out / "train"
        print(f"training the Q-learning policy first: {spec.count} random worlds (seeds "
              f"{spec.seed0}-{spec.seed0 + spec.count - 1}) x seeds 0-{args.train_seeds - 1}, "
              f"{args.cycles} cycles each, in process -> {train_out}")
        files, made = _training_worlds(None, spec, train_out / "worlds")
        _train(files, made, list(range(args.train_seeds)), args.cycles, train_out,
               graph=False, quiet=args.quiet, features=args.features)
        qtable, origin = train_out / "qtable.json", "trained now by `roger train` (in process)"
    trained = TrainedTable.of(qtable, world, origin)
    if trained.world_seen:
        print(f"roger compare: warning: {args.world} is one of the worlds {qtable} was "
              "trained on", file=sys.stderr)
    modes = [args.features] + [m for m in (getattr(args, "also_modes", None) or [])
                               if m != args.features]
    results = {}
    for mode in modes:
        out = args.out if mode == args.features else args.out / mode
        if len(modes) > 1:
            print(f"\nfeature mode {mode} -> {out}")
        results[mode] = _compare_mode(args, world, seeds, qtable, trained, mode, out)
        print()
        print((out / "table2.md").read_text())
        print(f"Q-learning policy: {qtable}, {origin}, greedy and frozen")
        for c in results[mode]["claims"]:
            print(f"  {c['verdict']:>26}: {c['claim']} ({c['holds_in']}/{c['seeds']} seeds)")
        c = results[mode]["completion"]
        if c is not None:
            print(f"  {c['verdict']:>26}: {c['claim']} ({c['every_object_visited']}/"
                  f"{c['runs']} runs; the robot's rule ended {c['complete']}/{c['runs']})")
    if len(modes) > 1:
        from roger_common.atomic import atomic_write_bytes
        from roger_experiments.compare import modes_markdown
        side = modes_markdown(results, str(args.world))
        atomic_write_bytes(args.out / "modes.md", side.encode())
        report = args.out / "report.md"
        atomic_write_bytes(report, (report.read_text() + "\n" + side).encode())
        print(side)
    print(f"\nfigures: {args.out / 'fig4.png'}, {args.out / 'fig5.png'}, "
          f"{args.out / 'fig6.png'}; report: {args.out / 'report.md'}")
    return 0


def _compare_mode(args: argparse.Namespace, world: WorldSpec, seeds: list[int], qtable: Path,
                  trained: TrainedTable, features: str, out: Path) -> dict:
    """Both policies, every seed, one feature mode, into ``out``: what ``compare`` returns."""
    from roger_experiments.compare import compare

    stable = args.stable_cycles
    if args.in_process:
        from roger_experiments.core_loop import run_core

        def run(policy: str, seed: int, run_dir: Path, complete: bool) -> dict:
            import time
            t0 = time.monotonic()
            recorder, _ = run_core(world, policy, COMPLETE_MAX if complete else args.cycles,
                                   seed=seed, out=run_dir,
                                   stop_when_complete=stable if complete else 0,
                                   qtable_path=qtable if policy == "qlearning" else None,
                                   learn=False, features=features)
            assert recorder is not None
            return recorder.close(time.monotonic() - t0)
    else:
        from roger_bringup.run import RunOptions, run_graph

        def run(policy: str, seed: int, run_dir: Path, complete: bool) -> dict:
            return run_graph(RunOptions(
                world=args.world, out=run_dir, policy=policy,
                cycles=None if complete else args.cycles, until_complete=complete,
                stable_cycles=stable, max_cycles=COMPLETE_MAX, seed=seed,
                qtable=qtable if policy == "qlearning" else None, learn=False,
                features=features, progress=not args.quiet))

    def run_one(policy: str, seed: int, run_dir: Path) -> dict:
        return run(policy, seed, run_dir, False)

    def run_complete(policy: str, seed: int, run_dir: Path) -> dict:
        return run(policy, seed, run_dir, True)
    return compare(args.world, seeds, out, run_one, progress=not args.quiet,
                   trained=trained, run_complete=run_complete if stable > 0 else None)


def cmd_train(args: argparse.Namespace) -> int:
    """``roger train``: Q-learning over worlds and seeds; writes the Q-table and Figure 6."""
    from roger_experiments.train import RandomWorlds

    count = args.random_worlds
    if count is None:
        count = 0 if args.worlds else RandomWorlds().count
    spec = RandomWorlds(count=count, seed0=args.world_seed0) if count > 0 else None
    worlds, made = _training_worlds(args.worlds, spec, args.out / "worlds")
    if not worlds:
        raise RogerError("roger train: no training world (give --worlds or --random-worlds)")
    seeds = list(range(args.seed0, args.seed0 + args.seeds))
    summary = _train(worlds, made, seeds, args.cycles, args.out, args.graph, args.quiet,
                     args.features)
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
             DEFAULT_WORLD, 204, 3, Path("runs/compare")),
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
        _add_features_arg(p_cmp)
        p_cmp.add_argument("--also-modes", nargs="*", default=(
            ["paper"] if name == "demo" else []), choices=("paper", "extended"),
            metavar="MODE",
            help="also run these feature modes (same seeds and Q-table) into OUT/MODE and "
                 "put Table 2 and the claims side by side in OUT/modes.md and report.md "
                 "(default: paper for demo, none for compare)")
        p_cmp.set_defaults(func=cmd_compare)
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
    p_t1.add_argument("--world", type=Path, default=DEFAULT_WORLD, help="world file (YAML)")
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
