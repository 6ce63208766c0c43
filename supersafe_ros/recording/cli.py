"""`supersafe record BAG`: record every topic of a running graph to a rosbag2 MCAP bag.

For graphs started some other way (``ros2 launch``, nodes by hand); ``supersafe team
--record BAG`` records a team it runs itself. Stops on Ctrl-C/SIGTERM or after
``--duration`` wall seconds, then closes the bag (metadata.yaml written).
"""
from __future__ import annotations

from pathlib import Path
import signal
import threading


def add_parser(subparsers):
    parser = subparsers.add_parser(
        'record', help='record every topic of a running graph to a rosbag2 MCAP bag folder',
        description=__doc__.splitlines()[0])
    parser.add_argument('bag', type=Path, help='new bag folder (BAG/metadata.yaml, BAG/BAG.mcap)')
    parser.add_argument('--duration', type=float, default=0.0,
                        help='stop after this many wall seconds (default: until Ctrl-C)')
    parser.add_argument('--domain-id', type=int, default=None, help='ROS_DOMAIN_ID (default: inherited)')
    parser.add_argument('--exclude', action='append', default=[], metavar='TOPIC',
                        help='a topic not to record (repeatable)')
    parser.set_defaults(func=run)
    return parser


def run(args) -> int:
    from ..ros_io.bag_recorder import start_recorder
    if args.bag.exists() and (not args.bag.is_dir() or any(args.bag.iterdir())):
        print(f'{args.bag}: exists and is not an empty folder; a bag is never overwritten')
        return 2
    stop = threading.Event()
    rec = start_recorder(args.bag, args.domain_id, exclude=args.exclude)
    # after rclpy.init, replacing its handlers: Ctrl-C must not shut the context down
    # before the recorder has taken what is queued
    old = {s: signal.signal(s, lambda *_: stop.set()) for s in (signal.SIGINT, signal.SIGTERM)}
    print(f'recording every topic to {args.bag} (Ctrl-C to stop)', flush=True)
    try:
        stop.wait(args.duration if args.duration > 0 else None)
    finally:
        info = rec.stop()
        for s, h in old.items():
            signal.signal(s, h)
    print(f'recorded {info.message_count} messages on {len(info.topics)} topics: {info.path}')
    for topic, why in sorted(rec.skipped.items()):
        print(f'  not recorded: {topic}: {why}')
    return 0
