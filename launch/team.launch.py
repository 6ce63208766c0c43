"""Bring up a supersafe_ros team in a ROS 2 install: `ros2 launch supersafe_ros team.launch.py`.

The same graph as `supersafe team` (both come from supersafe_ros.team.team_layout):
sim_clock, world, N x (dubins_robot, planner, safety_filter) in /robot_<i>, learner
and supervisor. Each node's parameters: share/supersafe_ros/config/<node>.yaml, then
``params_file`` (if given), then the layout's values (robots, seeds, step, rate factor,
use_sim_time, ``set``), which win.

Arguments (``ros2 launch supersafe_ros team.launch.py --show-args``): robots (2),
rate_factor (10.0), step (0.05), seed (0), duration (0 = run until stopped),
use_sim_time (true), supervisor / learner / filter (true), sensors (none | scan), learner_store ('' = a fresh
store for this launch), params_file (''), set ('' ; e.g. "supervisor.mu=1.0 world.n_obstacles=6"),
discovery_range (LOCALHOST), colorized_output (0).

The launch ends when the clock exits: with a duration, the clock exits (code 0) once it is
reached (``exit_at_duration``), and OnProcessExit -> Shutdown stops every node (SIGINT;
each exits 0). A clock that dies ends it too: without it nothing moves.
Example: ros2 launch supersafe_ros team.launch.py robots:=3 step:=0.1 set:="supervisor.mu=1.0"
"""

ARGUMENTS = [
    # name, default, description
    ('robots', '2', 'number of robots'),
    ('rate_factor', '10.0', 'sim seconds per wall second (0: as fast as possible)'),
    ('step', '0.05', 'sim seconds per clock step = 1 / robot rate (0.1 halves the CPU)'),
    ('seed', '0', 'world, sensor and supervisor seed'),
    ('duration', '0.0', 'sim seconds after which the clock stops (0: never)'),
    ('use_sim_time', 'true', 'every node but the clock follows /clock (the config files alone run '
                             'the robot, planner, world, supervisor and filters on the wall clock)'),
    ('supervisor', 'true', 'start the simulated supervisor'),
    ('learner', 'true', 'start the learner'),
    ('filter', 'true', 'start the safety filters (false: the planner drives the robot; testing only)'),
    ('sensors', 'none', 'none: the study\'s robots; scan: robots that publish only odometry and a laser scan '
                        'and take TwistStamped, planners that slow and stop, filters that read them'),
    ('learner_store', '', "the learner's intervention file ('' = a fresh file for this launch under "
                          '$XDG_DATA_HOME/supersafe_ros/runs/; name a file to resume a subject)'),
    ('params_file', '', 'a ROS 2 parameter file applied to every node after its config file '
                        "(the layout's own values still win; change those with the arguments "
                        'above or set)'),
    ('set', '', 'parameter overrides, space separated NODE.PARAM=VALUE '
                '(e.g. "supervisor.mu=1.0 world.n_obstacles=6")'),
    ('discovery_range', 'LOCALHOST', 'ROS_AUTOMATIC_DISCOVERY_RANGE of the team (LOCALHOST: DDS '
                                     'stays on this machine, as with `supersafe team`)'),
    ('colorized_output', '0', 'RCUTILS_COLORIZED_OUTPUT of the nodes (0: no colour escape codes)'),
]


def _flag(text: str) -> bool:
    value = text.strip().lower()
    if value not in ('true', 'false', '1', '0'):
        raise ValueError(f"expected true or false, got '{text}'")
    return value in ('true', '1')


def _nodes(context):
    # imported here: the module must stay importable (and parseable) without launch_ros
    from launch.actions import RegisterEventHandler, Shutdown
    from launch.event_handlers import OnProcessExit
    from launch_ros.actions import Node

    from supersafe_ros.team import CONFIG_FILES, config_dir, parse_overrides, team_layout

    def arg(name):
        return context.perform_substitution(_lc(name))

    layout = team_layout(
        n_robots=int(arg('robots')), rate_factor=float(arg('rate_factor')), seed=int(arg('seed')),
        duration=float(arg('duration')), step=float(arg('step')),
        overrides=parse_overrides(arg('set').split()),
        with_filter=_flag(arg('filter')), with_learner=_flag(arg('learner')),
        with_supervisor=_flag(arg('supervisor')), use_sim_time=_flag(arg('use_sim_time')),
        learner_store=arg('learner_store') or None, sensors=arg('sensors'))
    extra = [arg('params_file')] if arg('params_file') else []
    config = config_dir()
    actions = []
    for spec in layout:
        cfg = config / CONFIG_FILES[spec.kind]
        params = dict(spec.params)
        if spec.kind == 'sim_clock':     # its duration ends the launch (below)
            params['exit_at_duration'] = float(params.get('duration', 0.0)) > 0.0
        node = Node(
            package='supersafe_ros', executable=spec.executable,
            namespace=spec.namespace or '',
            parameters=([str(cfg)] if cfg.is_file() else []) + extra + [params],
            remappings=list(spec.remaps.items()),
            output='screen', emulate_tty=True)
        actions.append(node)
        if spec.kind == 'sim_clock':
            actions.append(RegisterEventHandler(OnProcessExit(
                target_action=node, on_exit=[Shutdown(reason='the sim clock exited (its duration reached)')])))
    return actions


def _lc(name):
    from launch.substitutions import LaunchConfiguration
    return LaunchConfiguration(name)


def generate_launch_description():
    from launch import LaunchDescription
    from launch.actions import DeclareLaunchArgument, OpaqueFunction, SetEnvironmentVariable

    return LaunchDescription(
        [DeclareLaunchArgument(name, default_value=default, description=description)
         for name, default, description in ARGUMENTS]
        + [SetEnvironmentVariable('ROS_AUTOMATIC_DISCOVERY_RANGE', _lc('discovery_range')),
           SetEnvironmentVariable('RCUTILS_COLORIZED_OUTPUT', _lc('colorized_output')),
           OpaqueFunction(function=_nodes)])
