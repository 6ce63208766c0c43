"""Bring up a supersafe_ros team in a ROS 2 install: `ros2 launch supersafe_ros team.launch.py`.

The same graph as `supersafe team` (both come from supersafe_ros.team.team_layout):
sim_clock, world, N x (dubins_robot, planner, safety_filter) in /robot_<i>, learner
and supervisor, parameters from share/supersafe_ros/config/*.yaml plus the
per-node values of the layout.

Arguments: robots (2), rate_factor (10.0), seed (0), duration (0 = run until
stopped; the clock stops advancing there), learner_store ('' = the learner's default),
discovery_range (LOCALHOST).
Example: ros2 launch supersafe_ros team.launch.py robots:=3 rate_factor:=5.0
"""


def _nodes(context):
    # imported here: the module must stay importable (and parseable) without launch_ros
    from launch_ros.actions import Node

    from supersafe_ros.team import CONFIG_FILES, config_dir, team_layout

    def arg(name):
        return context.perform_substitution(_lc(name))

    layout = team_layout(
        n_robots=int(arg('robots')), rate_factor=float(arg('rate_factor')), seed=int(arg('seed')),
        duration=float(arg('duration')), learner_store=arg('learner_store') or None)
    config = config_dir()
    actions = []
    for spec in layout:
        cfg = config / CONFIG_FILES[spec.kind]
        actions.append(Node(
            package='supersafe_ros', executable=spec.executable,
            namespace=spec.namespace or '',
            parameters=([str(cfg)] if cfg.is_file() else []) + [spec.params],
            remappings=list(spec.remaps.items()),
            output='screen', emulate_tty=True))
    return actions


def _lc(name):
    from launch.substitutions import LaunchConfiguration
    return LaunchConfiguration(name)


def generate_launch_description():
    from launch import LaunchDescription
    from launch.actions import DeclareLaunchArgument, OpaqueFunction, SetEnvironmentVariable

    return LaunchDescription([
        DeclareLaunchArgument('robots', default_value='2', description='number of robots'),
        DeclareLaunchArgument('rate_factor', default_value='10.0',
                              description='sim seconds per wall second (0: as fast as possible)'),
        DeclareLaunchArgument('seed', default_value='0', description='world, sensor and supervisor seed'),
        DeclareLaunchArgument('duration', default_value='0.0',
                              description='sim seconds after which the clock stops (0: never)'),
        DeclareLaunchArgument('learner_store', default_value='',
                              description="the learner's intervention file ('' = its default)"),
        DeclareLaunchArgument('discovery_range', default_value='LOCALHOST',
                              description='ROS_AUTOMATIC_DISCOVERY_RANGE of the team (LOCALHOST: '
                                          'DDS stays on this machine, as with `supersafe team`)'),
        SetEnvironmentVariable('ROS_AUTOMATIC_DISCOVERY_RANGE', _lc('discovery_range')),
        OpaqueFunction(function=_nodes),
    ])
