"""bag_player's command line: the playback options and their parsing (the player itself:
:mod:`hsa_bag.player`)."""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

from hsa_core import cli

DESCRIPTION = "bag_player: publish a bag into the live graph with the recorded timing."


@dataclass(frozen=True)
class Options:
    """What to play and how (see the module docstring)."""

    topics: tuple[str, ...]  # recorded names; empty = all
    remap: dict[str, str]
    rate: float = 1.0
    start_offset: float = 0.0  # s of bag time skipped at the start of every pass
    loops: int = 1  # passes; 0 = forever
    clock_hz: float = 0.0  # 0 = no /clock
    delay: float = 0.0  # s before the first message
    # s to wait for a subscriber on every awaited topic; 0 = don't
    wait_for_subscribers: float = 0.0
    wait_topics: tuple[
        str, ...
    ] = ()  # recorded names of the awaited topics; empty = every played topic
    busy_wait: float = 1e-3  # s busy-waited before each due time


def _remap(text: str) -> tuple[str, str]:
    """argparse type for FROM:=TO."""
    source, sep, target = text.partition(":=")
    if not sep or not source or not target:
        raise argparse.ArgumentTypeError(f"expected FROM:=TO, got {text!r}")
    return source, target


def parse_args(argv: list[str]) -> tuple[Path, Options]:
    """Bag path and options from the command line (without ROS arguments)."""
    parser = cli.ArgumentParser(prog="bag_player", description=DESCRIPTION)
    parser.add_argument("bag", type=Path, help="rosbag2 directory or .mcap file")
    parser.add_argument(
        "--topics",
        nargs="+",
        default=[],
        metavar="TOPIC",
        help="recorded topics to play (default all)",
    )
    parser.add_argument(
        "--remap",
        action="append",
        type=_remap,
        default=[],
        metavar="FROM:=TO",
        help="publish recorded topic FROM as TO (repeatable)",
    )
    parser.add_argument(
        "--rate", type=cli.positive, default=1.0, help="playback speed factor (2 = twice as fast)"
    )
    parser.add_argument(
        "--start-offset",
        type=cli.non_negative,
        default=0.0,
        metavar="S",
        help="skip the first S seconds of the bag",
    )
    parser.add_argument(
        "--loop",
        type=int,
        nargs="?",
        const=0,
        default=1,
        metavar="N",
        help="play N passes; without N, repeat until stopped",
    )
    parser.add_argument(
        "--clock",
        type=cli.positive,
        nargs="?",
        const=40.0,
        default=0.0,
        metavar="HZ",
        help="publish the playback time on /clock at HZ (default 40)",
    )
    parser.add_argument(
        "--delay",
        type=cli.non_negative,
        default=0.0,
        metavar="S",
        help="wait S seconds before playing",
    )
    parser.add_argument(
        "--wait-for-subscribers",
        type=cli.positive,
        nargs="?",
        const=30.0,
        default=0.0,
        metavar="TIMEOUT",
        help="first wait up to TIMEOUT s (default 30) for a subscriber per topic",
    )
    parser.add_argument(
        "--wait-topics",
        nargs="+",
        default=[],
        metavar="T",
        help="wait for subscribers on these recorded topics only (default: every played topic)",
    )
    parser.add_argument(
        "--busy-wait-ms",
        type=cli.non_negative,
        default=1.0,
        metavar="MS",
        help="busy-wait this long before each message instead of sleeping (default 1)",
    )
    args = parser.parse_args(argv)
    if args.loop < 0:
        parser.error("--loop N needs N >= 0")
    options = Options(
        topics=tuple(args.topics),
        remap=dict(args.remap),
        rate=args.rate,
        start_offset=args.start_offset,
        loops=args.loop,
        clock_hz=args.clock,
        delay=args.delay,
        wait_for_subscribers=args.wait_for_subscribers,
        wait_topics=tuple(args.wait_topics),
        busy_wait=args.busy_wait_ms * 1e-3,
    )
    return args.bag, options


def split_ros_args(argv: list[str]) -> tuple[list[str], list[str]]:
    """(our arguments, ``--ros-args … [--]`` for rclpy); FROM:=TO stays ours (rcl would take it for
    a remap rule)."""
    if "--ros-args" not in argv:
        return argv, []
    start = argv.index("--ros-args")
    end = argv.index("--", start) if "--" in argv[start:] else len(argv)
    return argv[:start] + argv[end + 1 :], argv[start:end]
