"""The ``roger`` command: ``roger run``, ``roger demo`` and friends."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from roger_common.errors import RogerError

#: Default world of the demo.
DEFAULT_WORLD = Path("worlds/table1.yaml")


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


def _run_options(args: argparse.Namespace):  # type: ignore[no-untyped-def]
    from roger_bringup.run import RunOptions
    cycles = None if args.until_complete else (args.cycles or 60)
    return RunOptions(
        world=args.world, out=args.out or Path("runs") / args.policy, policy=args.policy,
        cycles=cycles, until_complete=args.until_complete, stable_cycles=args.stable_cycles,
        seed=args.seed, qtable=args.qtable, memory=args.memory, learn=not args.no_learn,
        image_size=args.image_size, realtime=args.realtime, gui=args.gui,
        domain_id=args.domain_id, timeout_s=args.timeout, progress=not args.quiet)


def cmd_run(args: argparse.Namespace) -> int:
    """``roger run``: one run of the graph; prints the metrics."""
    from roger_bringup.run import run_graph
    metrics = run_graph(_run_options(args))
    print(json.dumps(metrics, indent=2))
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    """``roger demo``: the main job of ``make demo``."""
    from roger_bringup.run import RunOptions, run_graph
    rows = []
    for policy in ("straightforward", "qlearning"):
        out = args.out / policy
        metrics = run_graph(RunOptions(world=args.world, out=out, policy=policy,
                                       cycles=args.cycles, seed=args.seed))
        rows.append(metrics)
    keys = ("attention_shifts", "improvements", "positive_identifications", "new_objects",
            "map_updates", "objects_visited", "objects_in_world")
    print("\npolicy           " + " ".join(f"{k[:12]:>12}" for k in keys))
    for m in rows:
        print(f"{m['policy']:<16} " + " ".join(f"{m[k]:>12}" for k in keys))
    print(f"\noutputs (cycles.csv, metrics.json, node logs) under {args.out}")
    return 0


def main(argv: list[str] | None = None) -> None:
    """Entry point of ``roger``."""
    parser = argparse.ArgumentParser(prog="roger", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    p_run = sub.add_parser("run", help="run the multi-process graph once")
    _add_run_args(p_run)
    p_run.set_defaults(func=cmd_run)
    p_demo = sub.add_parser("demo", help="both policies on the default world (make demo)")
    p_demo.add_argument("--world", type=Path, default=DEFAULT_WORLD)
    p_demo.add_argument("--cycles", type=int, default=60)
    p_demo.add_argument("--seed", type=int, default=0)
    p_demo.add_argument("--out", type=Path, default=Path("runs/demo"))
    p_demo.set_defaults(func=cmd_demo)
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
