"""The ``roger`` command: ``roger run``, ``roger demo`` and friends."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from roger_common.errors import RogerError

#: Default world of the demo.
DEFAULT_WORLD = Path("worlds/table1.yaml")
#: World of ``make demo``: enough regions that 204 cycles do not run out of things to see.
DEMO_WORLD = Path("worlds/inspection.yaml")


def _add_run_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--world", type=Path, default=DEFAULT_WORLD, help="world file (YAML)")
    p.add_argument("--policy", choices=("straightforward", "qlearning"),
                   default="straightforward", help="attention policy (paper, section 4)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--cycles", type=int, default=None, help="control cycles to run (default 60)")
    g.add_argument("--until-complete", action="store_true",
                   help="run until every object was visited and no new representation "
                        "appeared for --stable-cycles cycles")
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
    p.add_argument("--image-size", type=int, default=128, help="retina size in pixels")
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
        image_size=args.image_size, realtime=args.realtime, gui=args.gui,
        domain_id=args.domain_id, timeout_s=args.timeout, progress=not args.quiet,
        view=args.view, record=args.record)


def cmd_run(args: argparse.Namespace) -> int:
    """``roger run``: one run of the graph; prints the metrics."""
    from roger_bringup.run import run_graph
    metrics = run_graph(_run_options(args))
    print(json.dumps(metrics, indent=2))
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    """``roger bench``: graph vs core, cycle vs floor, scaling; writes DIR/bench.json."""
    from roger_bringup.bench import main_bench
    result = main_bench(args.out, quick=args.quick)
    print(f"bench.json: {args.out / 'bench.json'}")
    return 0 if result else 1


def cmd_replay(args: argparse.Namespace) -> int:
    """``roger replay``: regenerate cycles.csv, metrics.json and figures from a recording."""
    from roger_bringup.record import replay
    print(json.dumps(replay(args.file, args.out), indent=2))
    return 0


def cmd_compare(args: argparse.Namespace) -> int:
    """``roger compare``: both policies, same world and seeds; Table 2 and Figures 4-6."""
    from roger_experiments.compare import compare

    seeds = list(range(args.seed0, args.seed0 + args.seeds))
    if args.in_process:
        from roger_experiments.core_loop import run_core
        from roger_sim.world import load_world
        world = load_world(args.world)

        def run_one(policy: str, seed: int, run_dir: Path) -> dict:
            import time
            t0 = time.monotonic()
            recorder, _ = run_core(world, policy, args.cycles, seed=seed, out=run_dir)
            assert recorder is not None
            return recorder.close(time.monotonic() - t0)
    else:
        from roger_bringup.run import RunOptions, run_graph

        def run_one(policy: str, seed: int, run_dir: Path) -> dict:
            return run_graph(RunOptions(world=args.world, out=run_dir, policy=policy,
                                        cycles=args.cycles, seed=seed,
                                        progress=not args.quiet))
    result = compare(args.world, seeds, args.out, run_one)
    print()
    print((args.out / "table2.md").read_text())
    for c in result["claims"]:
        print(f"  {c['verdict']:>26}: {c['claim']} ({c['holds_in']}/{c['seeds']} seeds)")
    print(f"\nfigures: {args.out / 'fig4.png'}, {args.out / 'fig5.png'}, "
          f"{args.out / 'fig6.png'}; report: {args.out / 'report.md'}")
    return 0


def cmd_train(args: argparse.Namespace) -> int:
    """``roger train``: Q-learning over worlds and seeds; writes the Q-table and TD curve."""
    import time

    from roger_experiments.train import train

    seeds = list(range(args.seed0, args.seed0 + args.seeds))
    if args.graph:
        from roger_bringup.run import RunOptions, run_graph

        def run_one(world: Path, seed: int, qtable: Path, run_dir: Path) -> dict:
            return run_graph(RunOptions(world=world, out=run_dir, policy="qlearning",
                                        cycles=args.cycles, seed=seed, qtable=qtable,
                                        progress=not args.quiet))
    else:
        from roger_experiments.core_loop import run_core
        from roger_sim.world import load_world

        def run_one(world: Path, seed: int, qtable: Path, run_dir: Path) -> dict:
            t0 = time.monotonic()
            # The loop saves the Q-table it learnt to ``qtable`` when it closes.
            recorder, _ = run_core(load_world(world), "qlearning", args.cycles, seed=seed,
                                   out=run_dir, qtable_path=qtable)
            assert recorder is not None
            return recorder.close(time.monotonic() - t0)
    summary = train(args.worlds, seeds, args.out, run_one)
    print(json.dumps(summary, indent=2))
    print(f"Q-table: {args.out / 'qtable.json'}; TD curve: {args.out / 'td_errors.png'}")
    return 0


def cmd_features(args: argparse.Namespace) -> int:
    """``roger features``: do the features of one object repeat across the robot's looks?"""
    from roger_experiments import feature_report
    from roger_sim.world import load_world

    result = feature_report.write(
        feature_report.collect_looks(load_world(args.world), seed=args.seed), args.out)
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
             DEMO_WORLD, 204, 3, Path("runs/demo"))):
        p_cmp = sub.add_parser(name, help=help_text)
        p_cmp.add_argument("--world", type=Path, default=world, help="world file (YAML)")
        p_cmp.add_argument("--cycles", type=int, default=cycles, help="control cycles per run")
        p_cmp.add_argument("--seeds", type=int, default=seeds, help="number of seeds")
        p_cmp.add_argument("--seed0", type=int, default=0, help="first seed")
        p_cmp.add_argument("--out", type=Path, default=out, help="output folder")
        p_cmp.add_argument("--in-process", action="store_true",
                           help="run the same core loop without ROS (faster, no graph)")
        p_cmp.add_argument("--quiet", action="store_true", help="no progress bars")
        p_cmp.set_defaults(func=cmd_compare)
    p_bench = sub.add_parser("bench", help="performance ratios of the graph (docs/performance.md)")
    p_bench.add_argument("--out", type=Path, default=Path("runs/bench"), help="output folder")
    p_bench.add_argument("--quick", action="store_true", help="a few cycles only (smoke test)")
    p_bench.set_defaults(func=cmd_bench)
    p_replay = sub.add_parser("replay", help="regenerate metrics and figures from a recording")
    p_replay.add_argument("file", type=Path, metavar="BAG",
                          help="bag folder or .mcap file written by roger run --record")
    p_replay.add_argument("--out", type=Path, default=Path("runs/replay"), help="output folder")
    p_replay.set_defaults(func=cmd_replay)
    p_train = sub.add_parser("train", help="train the Q-learning policy over worlds and seeds")
    p_train.add_argument("--worlds", type=Path, nargs="+",
                         default=[Path("worlds/table1.yaml"), Path("worlds/shapes.yaml")],
                         help="world files to train on, in order")
    p_train.add_argument("--seeds", type=int, default=2, help="seeds per world")
    p_train.add_argument("--seed0", type=int, default=0, help="first seed")
    p_train.add_argument("--cycles", type=int, default=204, help="control cycles per run")
    p_train.add_argument("--out", type=Path, default=Path("runs/train"), help="output folder")
    p_train.add_argument("--graph", action="store_true",
                         help="train through the multi-process graph instead of in process")
    p_train.add_argument("--quiet", action="store_true", help="no progress bars")
    p_train.set_defaults(func=cmd_train)
    p_feat = sub.add_parser("features", help="do the features repeat? within- vs "
                            "between-category spread of every feature, ROI purity")
    p_feat.add_argument("--world", type=Path, default=DEMO_WORLD, help="world file (YAML)")
    p_feat.add_argument("--seed", type=int, default=0, help="seed of the sensor noise")
    p_feat.add_argument("--out", type=Path, default=Path("runs/features"),
                        help="output folder")
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
