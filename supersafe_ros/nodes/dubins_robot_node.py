"""dubins_robot_node: one simulated Dubins robot (see supersafe_ros.sim.dubins_sim).

Topics (relative; run it in a namespace such as /robot_0):
  sub  cmd_vel            geometry_msgs/Twist        angular.z, clipped to +-w_max (linear.x ignored)
  sub  goal               geometry_msgs/PoseStamped  latched, from the world: a new goal = a new
                                                     trip (the sensor's miss draws start afresh)
  sub  /obstacle_markers  visualization_msgs/MarkerArray  latched, obstacle ids and centres
  sub  initialpose        geometry_msgs/PoseWithCovarianceStamped  frame map: teleport (scene
                                                     reset, as RViz's "2D Pose Estimate"); starts
                                                     a new trip (misses redrawn)
  pub  pose               geometry_msgs/PoseStamped  frame map, every step
  pub  detections         geometry_msgs/PoseArray    frame map, obstacle centres seen; on every
                                                     change and every detections_period, and
                                                     none before the robot knows the world
  pub  step_done          rosgraph_msgs/Clock        lockstep acknowledgement (see sim_clock_node)

``sensors: scan`` makes it a robot that publishes what a real one does: every step
``odom`` (nav_msgs/Odometry, frame ``frame_id``, child base_link, the speed and turn rate it
drove) and ``scan`` (sensor_msgs/LaserScan, frame base_link, ``scan_beams`` beams round the
full circle ray-cast against the world's discs of their own radii, ``sim.laser``; range_max =
``sensor_range``), both with the step's stamp. An obstacle the sensor misses for the trip
(``miss_probability``) is left out of the ray cast: this approach the scan does not see it.
``detections`` (the centres of the obstacles in the ray cast) still goes out as in 'none': the
world classifies an intervention as a false positive by what the near robots saw, and a
scan robot that said nothing would have every intervention near it counted as needed.
``pose`` stays (the simulator's ground truth, for the world and the supervisor).
``cmd_vel_stamped`` takes geometry_msgs/TwistStamped on cmd_vel; ``follow_speed`` drives at
the commanded linear.x clipped to [0, speed] (otherwise at speed).

Steps run on a timer of the node's clock: with use_sim_time they follow /clock.
Each step integrates the exact arc from the previous step time under the command
in force, but never more than ``max_step`` (default: one period, 1/rate): when sim
time jumps (the clock went on without this robot, e.g. its link was down) the rest
of the jump is a pause (see sim.dubins_sim: no motion, logged), so no command moves
the robot further than the one control period the filter judged it for. Lockstep: after
publishing the pose of step t the robot acknowledges t on ``step_done`` once a command
has arrived in reply (or at once when it has no live controller: parked or timed out),
so the clock never outruns the control loop.

Detections mean "I have looked". The simulated sensor looks at the world's obstacle set
(``/obstacle_markers``); until that set has arrived the robot publishes no detections at
all, because an empty message would tell its filter "no obstacle near" (a filter cannot
tell that from a sensor that has not looked yet, and passed the planner into an obstacle at
start-up: issue 22). Once the set is known and before the first step (sim time not started),
the robot repeats its detections from the initial pose every ``detections_period`` (at
least 4 times a second) on the steady clock, so its filter has them, and says it is ready,
before the clock starts (``supersafe_ros.team``).
"""
from __future__ import annotations

import math

from rclpy.clock import Clock as RosClock, ClockType
from rclpy.node import Node

from geometry_msgs.msg import PoseArray, PoseStamped, PoseWithCovarianceStamped, Twist, TwistStamped
from nav_msgs.msg import Odometry
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import LaserScan
from visualization_msgs.msg import MarkerArray


from ..ros_io import rosmsg
from ..sim.dubins_sim import LossySensor, RobotSim, TIMEOUT_BEHAVIORS
from ..sim.laser import beam_angles, ray_cast
from .common import LiveParameters, declare, run_node
from .markers import ObstacleMarkers


class DubinsRobotNode(Node):
    def __init__(self, node_name='dubins_robot', **kwargs):
        super().__init__(node_name, **kwargs)
        # the car and its sensor are fixed for the node's life (read-only); only how often
        # unchanged detections are repeated takes effect at run time
        p = lambda *a, **k: declare(self, *a, read_only=True, **k)  # noqa: E731
        x0 = p('initial_x', -17.0, 'initial x in map [m]', -1e4, 1e4)
        y0 = p('initial_y', 0.0, 'initial y in map [m]', -1e4, 1e4)
        th0 = p('initial_theta', 0.0, 'initial heading [rad], 0 = +x', -math.pi, math.pi)
        speed = p('speed', 3.0, 'fixed forward speed [m/s]', 0.01, 100.0)
        w_max = p('w_max', 1.0, 'turn-rate bound [rad/s]; commands are clipped to it', 0.0, 20.0)
        rate = p('rate', 20.0, 'integration and publishing rate [Hz of the node clock]', 1.0, 1000.0)
        rng_ = p('sensor_range', 10.0, 'obstacles within this distance of the robot are sensed [m]',
                 0.1, 1e3)
        miss = p('miss_probability', 0.2, 'probability that an obstacle is missed for a whole trip',
                 0.0, 1.0)
        timeout = p('command_timeout', 0.5, 'no cmd_vel for this long [s] -> fail-safe behaviour',
                    0.01, 100.0)
        behavior = p('timeout_behavior', 'loiter',
                     f'fail-safe after command_timeout: one of {TIMEOUT_BEHAVIORS} '
                     '(loiter = turn at +w_max on a circle of radius speed/w_max)')
        max_step = p('max_step', 0.0, 'most sim time integrated in one step [s]; the rest of a '
                     'sim-time jump is a pause (no motion); 0 = one period (1/rate)', 0.0, 100.0)
        seed = p('seed', -1, 'random seed of the sensor misses (-1: from the OS)', -1, 2**31 - 1)
        self.detections_period = declare(
            self, 'detections_period', 0.25,
            'detections are published when the seen set changes and at least this often [s]; '
            '0 = every step; live', 0.0, 100.0)
        self.live = LiveParameters(self)
        self.live.add('detections_period', lambda v: setattr(self, 'detections_period', v))
        self.lockstep = p('lockstep', True, 'acknowledge each step on step_done (for sim_clock_node)')
        self.frame = p('frame_id', rosmsg.MAP_FRAME, 'frame of pose and detections')
        self.sensors = p('sensors', 'none', 'none: detections (PoseArray of centres); scan: odom (Odometry) and '
                         'scan (LaserScan) instead')
        if self.sensors not in ('none', 'scan'):
            raise ValueError(f"sensors must be 'none' or 'scan', got {self.sensors!r}")
        beams = p('scan_beams', 360, 'sensors scan: beams round the full circle', 4, 100000)
        stamped = p('cmd_vel_stamped', False, 'cmd_vel is geometry_msgs/TwistStamped (false: Twist)')
        follow = p('follow_speed', False, 'drive at the commanded linear.x clipped to [0, speed] (false: at '
                   'speed whatever linear.x says)')

        self.robot = RobotSim([x0, y0, th0], speed=speed, omega_max=w_max,
                              command_timeout=timeout, timeout_behavior=behavior,
                              max_step=max_step if max_step > 0 else 1.0 / rate, follow_speed=follow)
        self.sensor = LossySensor(sensor_range=rng_, miss_probability=miss, seed=seed)
        self.obstacles = ObstacleMarkers()
        self.world_known = False    # the obstacle set has arrived: the sensor can look
        self.pending_ack = None     # sim time (ns) of a step awaiting its command
        self.last_seen = None       # ids in the last detections message
        self.last_detections_t = -float('inf')
        self.steps = 0

        self.pose_pub = self.create_publisher(PoseStamped, 'pose', rosmsg.QOS_STREAM)
        if self.sensors == 'scan':
            self.angles = beam_angles(beams)
            self.odom_pub = self.create_publisher(Odometry, 'odom', rosmsg.QOS_STREAM)
            self.scan_pub = self.create_publisher(LaserScan, 'scan', rosmsg.QOS_STREAM)
        # what it saw, for the world's false-positive rule (and a 'none' robot's filter)
        self.det_pub = self.create_publisher(PoseArray, 'detections', rosmsg.QOS_STREAM)
        self.ack_pub = self.create_publisher(Clock, 'step_done', rosmsg.QOS_ACK)
        self.create_subscription(TwistStamped if stamped else Twist, 'cmd_vel', self.on_cmd, rosmsg.QOS_STREAM)
        self.create_subscription(PoseStamped, 'goal', self.on_goal, rosmsg.QOS_LATCHED)
        self.create_subscription(MarkerArray, '/obstacle_markers', self.on_markers,
                                 rosmsg.QOS_LATCHED)
        self.create_subscription(PoseWithCovarianceStamped, 'initialpose', self.on_initialpose,
                                 rosmsg.QOS_EVENTS)
        self.timer = self.create_timer(1.0 / rate, self.step)
        # before the first step: detections from the initial pose, on the steady clock (sim
        # time may not run yet), so the filter knows what the robot sees before it moves
        self.start_timer = self.create_timer(
            self.start_period(), self.announce_before_start, clock=RosClock(clock_type=ClockType.STEADY_TIME))
        self.get_logger().info(
            f'robot at ({x0:.2f}, {y0:.2f}, {th0:.2f}) speed {speed} w_max {w_max} rate {rate} Hz, '
            f'sensor range {rng_} m, miss p {miss}, fail-safe {behavior} after {timeout} s')

    def start_period(self) -> float:
        """Steady seconds between detections before the first step."""
        return min(self.detections_period, 0.25) if self.detections_period > 0 else 0.25

    def announce_before_start(self):
        if self.steps > 0:
            self.start_timer.cancel()      # stepping: detections go with the poses
            return
        if self.world_known:
            stamp = self.get_clock().now().to_msg()
            if self.sensors == 'scan':
                self.publish_odometry(self.robot.state, 0.0, stamp)
                self.publish_scan(self.robot.state, stamp)
            ids, xy = self.obstacles.arrays()
            _, seen = self.sensor.sense(self.robot.state[:2], ids, xy)
            self.det_pub.publish(rosmsg.xy_to_posearray(seen, stamp, self.frame))

    def now_s(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def on_cmd(self, msg):
        twist = msg.twist if isinstance(msg, TwistStamped) else msg
        try:
            omega = rosmsg.twist_turn_rate(twist)
            self.robot.command(omega, self.now_s(), twist.linear.x)
        except ValueError as exc:
            self.get_logger().error(f'cmd_vel rejected: {exc}; keeping the previous command',
                                    throttle_duration_sec=1.0)
        # a reply, valid or not, ends the lockstep wait: waiting longer would not help
        if self.pending_ack is not None:
            self.ack(self.pending_ack)

    def on_goal(self, msg: PoseStamped):
        self.sensor.new_trip()

    def on_initialpose(self, msg: PoseWithCovarianceStamped):
        try:
            state = rosmsg.pose_to_state(PoseStamped(header=msg.header, pose=msg.pose.pose),
                                         self.frame)
            self.robot.teleport(state)
        except ValueError as exc:
            self.get_logger().error(f'initialpose rejected: {exc}; staying where it is')
            return
        self.sensor.new_trip()
        self.get_logger().info(f'teleported to ({state[0]:.2f}, {state[1]:.2f}, {state[2]:.2f})')

    def on_markers(self, msg: MarkerArray):
        try:
            self.obstacles.update(msg)
        except ValueError as exc:
            self.get_logger().error(f'/obstacle_markers rejected: {exc}')
            return
        if not self.world_known:
            self.world_known = True
            self.get_logger().info(f'obstacle set received ({len(self.obstacles.centres)} obstacles): '
                                   'publishing detections')
            self.announce_before_start()

    def ack(self, t_ns: int):
        self.pending_ack = None
        out = Clock()
        out.clock.sec, out.clock.nanosec = divmod(int(t_ns), 1_000_000_000)
        self.ack_pub.publish(out)

    def step(self):
        stamp = self.get_clock().now()
        now = stamp.nanoseconds * 1e-9
        state = self.robot.advance(now)
        if self.robot.last_pause > 0:
            self.get_logger().warn(
                f'sim time jumped {self.robot.last_pause + self.robot.max_step:.3f} s: moved for '
                f'{self.robot.max_step:.3f} s, paused for {self.robot.last_pause:.3f} s '
                f'({self.robot.paused:.3f} s paused in all)', throttle_duration_sec=1.0)
        self.steps += 1
        msg_stamp = stamp.to_msg()
        self.pose_pub.publish(rosmsg.state_to_pose(state, msg_stamp, self.frame))
        if self.sensors == 'scan':
            self.publish_odometry(state, now, msg_stamp)
            if self.world_known:
                self.publish_scan(state, msg_stamp)
        if self.world_known:
            self.publish_detections(state, now, msg_stamp)
        if self.lockstep:
            if self.robot.mode(now) == 'commanded':
                self.pending_ack = stamp.nanoseconds   # acknowledged when the reply arrives
            else:
                self.ack(stamp.nanoseconds)

    def publish_odometry(self, state, now, msg_stamp):
        msg = Odometry()
        msg.header.stamp, msg.header.frame_id, msg.child_frame_id = msg_stamp, self.frame, 'base_link'
        msg.pose.pose = rosmsg.state_to_pose(state).pose
        moving = self.robot.mode(now) != 'parked'
        msg.twist.twist.linear.x = self.robot.linear(now) if moving else 0.0
        msg.twist.twist.angular.z = float(self.robot.control(now) or 0.0)
        self.odom_pub.publish(msg)

    def publish_scan(self, state, msg_stamp):
        """The ranges to the obstacles this trip's sensor does not miss (sim.laser)."""
        ids, xy = self.obstacles.arrays()
        seen_ids, seen = self.sensor.sense(state[:2], ids, xy)
        radii = [self.obstacles.radii[i] for i in seen_ids.tolist()]
        msg = LaserScan()
        msg.header.stamp, msg.header.frame_id = msg_stamp, 'base_link'
        msg.angle_min, msg.angle_increment = float(self.angles[0]), float(self.angles[1] - self.angles[0])
        msg.angle_max = float(self.angles[-1])
        msg.range_min, msg.range_max = 0.05, float(self.sensor.sensor_range)
        # an obstacle is seen by its centre's distance (sense); the cast sees its surface within range
        msg.ranges = ray_cast(state, self.angles, seen, radii, self.sensor.sensor_range + 1e-9).tolist()
        self.scan_pub.publish(msg)

    def publish_detections(self, state, now, msg_stamp):
        ids, xy = self.obstacles.arrays()
        seen_ids, seen = self.sensor.sense(state[:2], ids, xy)
        # detections change rarely: send them on change and as a heartbeat, which keeps
        # every consumer fresh at a fraction of the per-step traffic
        seen_key = tuple(seen_ids.tolist())
        if now < self.last_detections_t:          # sim time restarted
            self.last_detections_t = -float('inf')
        if (seen_key != self.last_seen
                or now - self.last_detections_t >= self.detections_period - 1e-9):
            self.det_pub.publish(rosmsg.xy_to_posearray(seen, msg_stamp, self.frame))
            self.last_seen = seen_key
            self.last_detections_t = now


def main(args=None):
    return run_node(DubinsRobotNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
