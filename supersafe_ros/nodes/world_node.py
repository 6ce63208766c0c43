"""world_node: the team task (supersafe_ros.sim.world) on topics.

  sub  /<robot>/pose           geometry_msgs/PoseStamped  trips and crashes, per pose
  sub  /<robot>/detections     geometry_msgs/PoseArray    what each robot saw (FP classification)
  sub  /interventions          geometry_msgs/PoseStamped  removal request: frame obstacle_<id>,
                                                          pose of the robot relative to it
  sub  /world/set_obstacles    geometry_msgs/PoseArray    frame map: replace every obstacle by discs
                                                          at these centres, with new ids (scene reset)
  pub  /obstacles              geometry_msgs/PoseArray    latched, centres (map), on change
  pub  /obstacle_markers       visualization_msgs/MarkerArray  latched, DELETEALL + one
                                                          CYLINDER per obstacle (id = obstacle id)
  pub  /<robot>/goal           geometry_msgs/PoseStamped  latched; each new goal = a new trip
  pub  /world/stats            diagnostic_msgs/DiagnosticStatus  latched; sim_time = the time up to
                                                          which every robot's poses are counted;
                                                          each time that passes a multiple of
                                                          stats_period, after every intervention,
                                                          and (if anything changed) every wall second
  pub  /world/intervention_log diagnostic_msgs/DiagnosticStatus  one per accepted intervention
  pub  /world/events           diagnostic_msgs/DiagnosticStatus  one per trip and per crash
  pub  /world/step_done        rosgraph_msgs/Clock        newest sim time whose poses of every robot
                                                          are counted (lockstep observer)
  sub  /<robot>/safety_filter/state  diagnostic_msgs/DiagnosticStatus  the filter's action (pass /
                                                          override / fail_safe), for the H2 measures
  sub  /world/reset            diagnostic_msgs/DiagnosticStatus  values seed (int): a new game on a
                                                          running graph: counts, measures, obstacle
                                                          layout (ids from 0) and goals start afresh
                                                          from that seed; /world/stats then says
                                                          resets = n (the study's kept-alive graph)

/world/stats also carries the H2 measures of sim/efficiency.py (path_per_trip,
avoidance_length, avoidance_total, avoidance_arcs, override_fraction, min_clearance,
path_length), counted from every pose and the filter's last reported action.

Robots are listed in the ``robots`` parameter (namespaces). An intervention naming an
unknown obstacle (already removed, or not an obstacle frame) is rejected and logged.
"""
from __future__ import annotations

from dataclasses import replace

from rclpy.clock import Clock as RosClock, ClockType
from rclpy.node import Node
from rclpy.time import Time

from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseArray, PoseStamped
from visualization_msgs.msg import MarkerArray

from ..ros_io import rosmsg
from ..sim.world import World, WorldConfig
from .common import LiveParameters, StepAcknowledger, declare, run_node
from .markers import obstacles_to_markers

# deep queues: the world must see every pose (a crash can last a single step)
QOS_EVERY_POSE = rosmsg.QOS_EVERY_SAMPLE


class WorldNode(Node):
    def __init__(self, node_name='world', **kwargs):
        super().__init__(node_name, **kwargs)
        # the field, the obstacles' layout, the robots and the score's weights are fixed
        # for a run (read-only); the judging tolerances take effect at run time (live)
        p = lambda *a, **k: declare(self, *a, read_only=True, **k)  # noqa: E731
        live = lambda *a, **k: declare(self, *a, **k)  # noqa: E731
        d = WorldConfig()
        cfg = WorldConfig(
            half_width=p('half_width', d.half_width, 'field spans x in +-half_width [m]', 1.0, 1e4),
            half_height=p('half_height', d.half_height, 'field spans y in +-half_height [m]', 1.0, 1e4),
            goal_x=p('goal_x', d.goal_x, 'goal lines at x = +-goal_x; crossing one ends a trip [m]',
                     0.1, 1e4),
            n_obstacles=p('n_obstacles', d.n_obstacles, 'number of obstacles', 0, 1000),
            radius=p('radius', d.radius, 'obstacle radius [m]', 0.01, 100.0),
            # [0.0] (the default) = every obstacle of radius
            radii=tuple(p('radii', [0.0], 'obstacle i has radius radii[i mod len] (several sizes in turn) [m]; '
                          '[0.0] = every obstacle of radius')),
            crash_tolerance=live('crash_tolerance', d.crash_tolerance,
                                 'a robot this close to the rim, inside, only grazes: not a crash [m]',
                                 0.0, 10.0),
            spacing=p('spacing', d.spacing, 'least gap between obstacle discs [m]', 0.0, 100.0),
            goal_margin=p('goal_margin', d.goal_margin,
                          'obstacle centres stay this far inside the goal lines [m]', 0.0, 1e3),
            respawn_clearance=live('respawn_clearance', d.respawn_clearance,
                                   'a new obstacle appears at least this far from every robot [m]',
                                   0.0, 1e3),
            near_distance=live('near_distance', d.near_distance,
                               'robots within this distance of a removed obstacle decide whether the '
                               'intervention was a false positive [m]', 0.01, 1e3),
            detection_tolerance=live('detection_tolerance', d.detection_tolerance,
                                     'a detection this close to a centre names that obstacle [m]',
                                     0.001, 100.0),
            trip_reward=p('trip_reward', d.trip_reward, 'score per completed trip', 0.0, 1e6),
            crash_penalty=p('crash_penalty', d.crash_penalty, 'score lost per crash', 0.0, 1e6),
            intervention_penalty=p('intervention_penalty', d.intervention_penalty,
                                   'score lost per intervention (paper: half a crash)', 0.0, 1e6),
        )
        self.robots = [r.strip('/') for r in p('robots', ['robot_0'], 'robot namespaces in the team')]
        seed = p('seed', 0, 'random seed of obstacle placement and goals (-1: from the OS)',
                 -1, 2**31 - 1)
        stats_period = live('stats_period', 1.0, 'sim seconds between /world/stats messages; live',
                            0.01, 1e4)
        self.match_tolerance = live('robot_match_tolerance', 1.0,
                                    'an intervention pose names the robot within this distance [m]',
                                    0.001, 100.0)
        self.respawn = live('respawn', True, 'an intervention spawns a replacement obstacle '
                            '(false: it only removes, as in the Phase II scenes); live')
        self.world = World(cfg, self.robots, seed=None if seed < 0 else seed)

        self.obstacles_pub = self.create_publisher(PoseArray, '/obstacles', rosmsg.QOS_LATCHED)
        self.markers_pub = self.create_publisher(MarkerArray, '/obstacle_markers', rosmsg.QOS_LATCHED)
        self.stats_pub = self.create_publisher(DiagnosticStatus, '/world/stats', rosmsg.QOS_LATCHED)
        self.log_pub = self.create_publisher(DiagnosticStatus, '/world/intervention_log',
                                             rosmsg.QOS_LOG)
        self.events_pub = self.create_publisher(DiagnosticStatus, '/world/events', rosmsg.QOS_LOG)
        self.acks = StepAcknowledger(self, self.robots)
        self.goal_pubs = {}
        for r in self.robots:
            self.goal_pubs[r] = self.create_publisher(PoseStamped, f'/{r}/goal', rosmsg.QOS_LATCHED)
            self.acks.watch(self.create_subscription(PoseStamped, f'/{r}/pose',
                                                     lambda m, r=r: self.on_pose(r, m), QOS_EVERY_POSE))
            self.create_subscription(PoseArray, f'/{r}/detections',
                                     lambda m, r=r: self.on_detections(r, m), QOS_EVERY_POSE)
        self.create_subscription(PoseStamped, '/interventions', self.on_intervention,
                                 rosmsg.QOS_EVENTS)
        self.create_subscription(PoseArray, '/world/set_obstacles', self.on_set_obstacles,
                                 rosmsg.QOS_EVENTS)
        self.add_study_hooks()
        heartbeat = p('stats_heartbeat', 1.0,
                      'wall seconds between /world/stats messages sent because counts changed '
                      'between sim-time reports (e.g. after the clock stopped)', 0.01, 3600.0)
        self.stats_period_ns = int(round(stats_period * 1e9))
        self.live = LiveParameters(self)
        for name in ('crash_tolerance', 'respawn_clearance', 'near_distance', 'detection_tolerance'):
            self.live.add(name, lambda v, name=name: self.set_config(name, v))
        self.live.add('robot_match_tolerance', lambda v: setattr(self, 'match_tolerance', v))
        self.live.add('respawn', lambda v: setattr(self, 'respawn', v))
        self.live.add('stats_period', lambda v: setattr(self, 'stats_period_ns', int(round(v * 1e9))))
        self.stats_sent = None
        # sim-time statistics are driven by the poses themselves (below); this steady
        # timer only makes sure changed counts go out when no report is due
        self.create_timer(heartbeat, self.stats_heartbeat, clock=RosClock(clock_type=ClockType.STEADY_TIME))
        self.publish_obstacles()
        self.publish_stats()
        self.get_logger().info(f'world: {cfg.n_obstacles} obstacles r={cfg.radii or cfg.radius}, '
                               f'robots {self.robots}')

    def set_config(self, name, value):
        self.world.config = replace(self.world.config, **{name: value})

    def now_s(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def publish_obstacles(self):
        ids, xy = self.world.obstacle_arrays()
        stamp = self.get_clock().now().to_msg()
        self.obstacles_pub.publish(rosmsg.xy_to_posearray(xy, stamp))
        radii = self.world.config.radius_of(ids) if self.world.config.radii else self.world.config.radius
        self.markers_pub.publish(obstacles_to_markers(ids, xy, radii, stamp))

    def publish_goal(self, robot):
        goal = self.world.robots[robot].goal
        r = self.world.robots[robot]
        heading = 0.0 if r.side > 0 else 3.141592653589793
        self.goal_pubs[robot].publish(rosmsg.state_to_pose((goal[0], goal[1], heading),
                                                           self.get_clock().now().to_msg()))

    def stats_values(self) -> dict:
        values = dict(self.world.stats())
        values['sim_time'] = f'{max(self.acks.sent, 0) * 1e-9:.3f}'
        for name, r in self.world.robots.items():
            values[f'{name}/trips'] = r.trips
            values[f'{name}/crashes'] = r.crashes
            values[f'{name}/detected'] = len(r.detections)
        values['relaxed_spawns'] = self.world.relaxed_spawns
        values['resets'] = self.resets
        values.update({k: f'{v:.4f}' if isinstance(v, float) else v
                       for k, v in self.world.efficiency().items()})
        return values

    def publish_stats(self, values=None):
        self.stats_sent = values or self.stats_values()
        self.stats_pub.publish(rosmsg.make_diagnostic('world', self.stats_sent))

    def stats_heartbeat(self):
        values = self.stats_values()
        if values != self.stats_sent:
            self.publish_stats(values)

    def on_pose(self, robot, msg: PoseStamped):
        try:
            self.count_pose(robot, msg)
        finally:
            advanced = self.acks.processed(robot, msg.header.stamp)   # dealt with, even if rejected
            if advanced and advanced[1] // self.stats_period_ns > max(advanced[0], 0) // self.stats_period_ns:
                self.publish_stats()

    def count_pose(self, robot, msg: PoseStamped):
        try:
            state = rosmsg.pose_to_state(msg)
            first = self.world.robots[robot].position is None
            events = self.world.update_pose(robot, state, Time.from_msg(msg.header.stamp).nanoseconds * 1e-9)
        except ValueError as exc:
            self.get_logger().error(f'pose of {robot} rejected: {exc}', throttle_duration_sec=1.0)
            return
        t = Time.from_msg(msg.header.stamp).nanoseconds * 1e-9
        if first or events['trip']:
            self.publish_goal(robot)
        if events['trip']:
            self.events_pub.publish(rosmsg.make_diagnostic('trip', {
                'robot': robot, 'time': f'{t:.3f}', 'trips': self.world.robots[robot].trips}))
        for oid in events['crashed']:
            self.get_logger().warn(f'{robot} crashed into obstacle {oid} at t={t:.2f}')
            self.events_pub.publish(rosmsg.make_diagnostic('crash', {
                'robot': robot, 'obstacle': oid, 'time': f'{t:.3f}',
                'x': f'{state[0]:.3f}', 'y': f'{state[1]:.3f}'}, level=1))

    def on_detections(self, robot, msg: PoseArray):
        try:
            xy = rosmsg.posearray_to_xy(msg)
            self.world.update_detections(robot, xy, Time.from_msg(msg.header.stamp).nanoseconds * 1e-9)
        except ValueError as exc:
            self.get_logger().error(f'detections of {robot} rejected: {exc}', throttle_duration_sec=1.0)

    # -- the study's kept-alive graph and H2 measures (additive hooks) ----------------------
    def add_study_hooks(self):
        self.resets = 0
        for r in self.robots:
            self.create_subscription(DiagnosticStatus, f'/{r}/safety_filter/state',
                                     lambda m, r=r: self.on_filter_state(r, m), rosmsg.QOS_STREAM)
        self.create_subscription(DiagnosticStatus, '/world/reset', self.on_reset, rosmsg.QOS_EVENTS)

    def on_filter_state(self, robot, msg: DiagnosticStatus):
        action = rosmsg.diagnostic_values(msg).get('action')
        if action is None:
            self.get_logger().error(f'{robot}/safety_filter/state without an action: ignored',
                                    throttle_duration_sec=5.0)
            return
        self.world.set_filter_action(robot, action)

    def on_reset(self, msg: DiagnosticStatus):
        values = rosmsg.diagnostic_values(msg)
        try:
            seed = int(values.get('seed', 0))
            if not -1 <= seed <= 2**31 - 1:
                raise ValueError(f'seed {seed} out of range')
            world = World(self.world.config, self.robots, seed=None if seed < 0 else seed)
        except ValueError as exc:
            self.get_logger().error(f'/world/reset rejected: {exc}; the game goes on unchanged')
            return
        self.world = world
        self.resets += 1
        self.publish_obstacles()
        self.publish_stats()
        self.get_logger().info(f'world reset {self.resets}: seed {seed}, '
                               f'{len(self.world.obstacles)} obstacles')

    def on_set_obstacles(self, msg: PoseArray):
        try:
            ids = self.world.set_obstacles(rosmsg.posearray_to_xy(msg))
        except ValueError as exc:
            self.get_logger().error(f'/world/set_obstacles rejected: {exc}; obstacles unchanged')
            return
        self.publish_obstacles()
        self.get_logger().info(f'obstacles replaced: ids {ids}')

    def on_intervention(self, msg: PoseStamped):
        try:
            oid = rosmsg.parse_obstacle_frame(msg.header.frame_id)
            rel = rosmsg.pose_to_state(msg, frame=None)
        except rosmsg.MessageError as exc:
            self.get_logger().error(f'intervention rejected: {exc}')
            return
        if oid not in self.world.obstacles:
            self.get_logger().error(f'intervention rejected: obstacle {oid} does not exist '
                                    '(already removed?)')
            return
        centre = self.world.obstacles[oid]
        robot = self.world.robot_at(centre + rel[:2], self.match_tolerance)
        t = Time.from_msg(msg.header.stamp).nanoseconds * 1e-9 or self.now_s()
        relaxed = self.world.relaxed_spawns
        record, new_id = self.world.intervene(oid, t, robot, respawn=self.respawn)
        if self.world.relaxed_spawns > relaxed:
            self.get_logger().warn(f'no room for obstacle {new_id} with the full spacing and clearance: '
                                   'placed with relaxed rules (see relaxed_spawns in /world/stats)')
        self.publish_obstacles()
        self.log_pub.publish(rosmsg.make_diagnostic('intervention', {
            'obstacle': oid, 'robot': robot or 'unknown', 'false_positive': record.false_positive,
            'time': f'{t:.3f}', 'near_robots': ','.join(record.near_robots),
            'undetected_by': ','.join(record.undetected_by),
            'new_obstacle': 'none' if new_id is None else new_id,
            'rel_x': f'{rel[0]:.4f}', 'rel_y': f'{rel[1]:.4f}', 'rel_theta': f'{rel[2]:.4f}'}))
        self.get_logger().info(f'intervention on obstacle {oid} for {robot}: '
                               f'{"false positive" if record.false_positive else "needed"}; '
                               f'new obstacle {"none" if new_id is None else new_id}')
        self.publish_stats()


def main(args=None):
    return run_node(WorldNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
