"""`supersafe`: the package's command-line tool (also `ros2 run supersafe_ros supersafe`).

Each subcommand lives beside the code it fronts; a module registers its
subcommand with ``add_parser(subparsers)`` and sets ``func`` on the parser.
Modules are imported only when listed here, so `supersafe reach` never loads rclpy.
"""
from __future__ import annotations

import argparse
import importlib
import sys

# (module, help) in the order they appear in --help
SUBCOMMANDS = [
    ('supersafe_ros.reach.cli', 'reach / library: compute avoid values and the candidate library'),
    ('supersafe_ros.learning.cli', 'fit: learn a supervisor safe set from interventions'),
    ('supersafe_ros.team_cli', 'team: run the ROS 2 node graph as separate processes'),
    ('supersafe_ros.study.cli', 'study / demo: the paper study in simulation'),
    ('supersafe_ros.recording.cli', 'record: record every topic to a rosbag2 MCAP bag'),
    ('supersafe_ros.session.runner', "session: the paper's protocol for one person in the console"),
    ('supersafe_ros.study.power', 'power: participants needed, from a simulated study'),
    ('supersafe_ros.cache_cli', 'cache: the files the package keeps (sizes, where), and clearing them'),
]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog='supersafe', description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest='command', metavar='COMMAND')
    for module_name, _ in SUBCOMMANDS:
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if exc.name and module_name.startswith(exc.name):
                continue  # that part of the package is not there (yet)
            raise
        module.add_parser(sub)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, 'func', None):
        parser.print_help()
        return 2
    return int(args.func(args) or 0)


if __name__ == '__main__':
    sys.exit(main())
