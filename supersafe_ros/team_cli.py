"""`supersafe team`: run the ROS 2 node graph of a robot team as separate processes.

The command line over ``team`` (the graph's layout, ``team_processes``, and its runner,
``run_team``) and ``hosts.placement`` (the same processes over K network namespaces,
``--hosts K``): the options become those modules' arguments here, so neither of them
reads an argparse namespace.
"""
from __future__ import annotations

from pathlib import Path

from .hosts.placement import run_on_hosts
from .team import default_log_dir, exit_status, parse_overrides, run_team, team_processes


def add_parser(subparsers):
    parser = subparsers.add_parser(
        'team', help='run the ROS 2 node graph of a robot team as separate processes',
        description=__doc__.splitlines()[0])
    parser.add_argument('--robots', type=int, default=2, help='number of robots (default 2)')
    parser.add_argument('--rate-factor', type=float, default=None,
                        help='sim seconds per wall second (0: as fast as possible; default 10, '
                             'or 1 with --console: a person watches in real time)')
    parser.add_argument('--step', type=float, default=0.05,
                        help='sim seconds per clock step = 1 / robot rate (default 0.05; 0.1 runs '
                             'about twice as fast on a busy machine)')
    parser.add_argument('--seed', type=int, default=0, help='seed of world, sensors, supervisor')
    parser.add_argument('--duration', type=float, default=0.0,
                        help='stop after this many sim seconds (default: run until Ctrl-C)')
    parser.add_argument('--timeout', type=float, default=0.0, help='stop after this many wall seconds')
    parser.add_argument('--domain-id', type=int, default=None, help='ROS_DOMAIN_ID (default: inherited)')
    parser.add_argument('--log-dir', type=Path, default=None,
                        help='per-process logs go here (default $TMPDIR/supersafe-team-<pid>)')
    parser.add_argument('--learner-store', type=Path, default=None,
                        help="the learner's intervention file (default <log-dir>/interventions.jsonl: a "
                             'fresh subject per run, as the default log folder is new for each run; a file '
                             'that holds data, e.g. in a reused --log-dir, is resumed)')
    parser.add_argument('--no-filter', action='store_true',
                        help='wire cmd_vel_nav straight into cmd_vel (testing only)')
    parser.add_argument('--no-learner', action='store_true', help='leave the learner out')
    parser.add_argument('--sensors', choices=('none', 'scan'), default='none',
                        help='scan: robots that publish only odometry and a laser scan and take TwistStamped, '
                        'planners that slow and stop at their goals, filters reading them (docs/topics.md)')
    parser.add_argument('--no-supervisor', action='store_true', help='leave the supervisor out')
    parser.add_argument('--console', action='store_true',
                        help='also serve the supervisor console (a web page) and print its URL')
    parser.add_argument('--console-port', type=int, default=8765,
                        help='TCP port of the console on 127.0.0.1 (default 8765)')
    parser.add_argument('--set', action='append', default=[], metavar='NODE.PARAM=VALUE',
                        help='parameter override, e.g. --set supervisor.mu=1.0 (repeatable)')
    parser.add_argument('--params-file', action='append', default=[], type=Path, metavar='FILE',
                        help='a ROS 2 parameter file applied to every node after its config file '
                             '(e.g. /**/supervisor: ros__parameters: {mu: 1.0}); the team\'s own values '
                             '(robots, seeds, step, rate factor, use_sim_time) still win: change those '
                             'with their options or --set; repeatable')
    parser.add_argument('--record', type=Path, default=None, metavar='BAG',
                        help='record every topic to a new rosbag2 MCAP bag folder BAG '
                             '(ros2 bag play BAG, or open BAG/BAG.mcap in Foxglove)')
    parser.add_argument('--print-argv', action='store_true', help='print the processes and exit')
    parser.add_argument('--hosts', type=int, default=1, metavar='K',
                        help='run across K >= 2 hosts: private network namespaces this command '
                             'makes and removes (needs root); host 0 runs world, learner, '
                             'supervisor and clock, the robots are dealt over hosts 1..K-1')
    parser.add_argument('--discovery-server', action='store_true',
                        help='with --hosts: Fast DDS discovery server on host 0 instead of '
                             'multicast discovery')
    parser.set_defaults(func=run)
    return parser


def run(args) -> int:
    log_dir = args.log_dir or default_log_dir()
    rate_factor = args.rate_factor if args.rate_factor is not None else (1.0 if args.console else 10.0)
    argvs = team_processes(
        args.robots, rate_factor, args.seed, args.duration,
        overrides=parse_overrides(args.set), step=args.step,
        with_filter=not args.no_filter, with_learner=not args.no_learner,
        with_supervisor=not args.no_supervisor,
        learner_store=args.learner_store or log_dir / 'interventions.jsonl',
        params_files=[p.resolve() for p in args.params_file],
        console_port=args.console_port if args.console else None, sensors=args.sensors)
    record = getattr(args, 'record', None)
    if record is not None and record.exists() and (not record.is_dir() or any(record.iterdir())):
        print(f'--record {record}: exists and is not an empty folder; a bag is never overwritten')
        return 2
    if (args.hosts > 1 or args.discovery_server) and record is not None:
        print('--record is not available with --hosts yet: record on host 0 with `supersafe record`')
        return 2
    if args.hosts > 1 or args.discovery_server:
        def run_placed(placed_argvs, placed_log_dir):
            return run_team(placed_argvs, args.duration, args.timeout, args.domain_id, placed_log_dir)
        return run_on_hosts(argvs, args.hosts, log_dir, run_placed,
                            with_discovery_server=args.discovery_server, print_argv=args.print_argv)
    if args.print_argv:
        for argv in argvs:
            print(' '.join(argv))
        return 0
    if args.console:
        print(f'console: http://127.0.0.1:{args.console_port}/', flush=True)
    result = run_team(argvs, args.duration, args.timeout, args.domain_id, log_dir,
                      record=record)
    return exit_status(result, log_dir)
