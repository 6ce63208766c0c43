"""supervisor_node: the simulated noisy idealized supervisor (paper Sec. III-B).

Its internal value function V_S is its own: a Dubins car with the supervisor's
belief of the turn-rate bound ``w_max``, obstacle ``radius`` and ``horizon``
(computed or loaded from the cache by reach.library.load_or_solve). It never reads
the learner's value function. It watches every robot pose against every obstacle
and, per approach, raises an alarm when V_S(x_rel) <= mu + w, w ~ N(0, sigma^2) drawn once
per approach (supersafe_ros.sim.watcher). Parameter ``model`` chooses what it does with an
alarm (supersafe_ros.sim.supervisor_models): ``memoryless`` (the paper's) intervenes at
once; ``attentive`` does not while the robot's turns away from that obstacle in this
approach have convinced it that the robot saw it (``convince_angle``, ``doubt_horizon``,
``doubt_window``).

  sub  /<robot>/pose         geometry_msgs/PoseStamped  every pose (deep queue)
  sub  /obstacle_markers     visualization_msgs/MarkerArray  latched, obstacle ids and centres
  pub  /interventions        geometry_msgs/PoseStamped  the robot's pose relative to the obstacle
                             (obstacle at the origin, axes as map) where it crossed the level,
                             interpolated between poses (see sim.watcher); frame obstacle_<id>,
                             stamp = sim time of the crossing. The world removes that obstacle.
  pub  /supervisor/decisions diagnostic_msgs/DiagnosticStatus  robot, obstacle, V_S, threshold
  pub  /supervisor/step_done rosgraph_msgs/Clock        newest sim time whose poses of every robot
                             are judged (lockstep observer); its first message (0, ready) waits
                             for every robot's pose publisher and for ``interventions_readers``
                             matched readers of /interventions
  sub  /supervisor/reset     diagnostic_msgs/DiagnosticStatus  values seed, and optionally mu, sigma,
                             w_max: forget every encounter and judge afresh with these (the study's
                             kept-alive graph starts each game so; a new w_max loads its V_S from
                             the cache). Logged as "supervisor reset: ..."
"""
from __future__ import annotations

from rclpy.node import Node
from rclpy.time import Time

from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from visualization_msgs.msg import MarkerArray

from ..ros_io import rosmsg
from ..reach.grid import Grid
from ..sim.supervisor_models import DEFAULT_MODEL, MODELS, AttentiveParams
from ..sim.watcher import Watcher
from .common import LiveParameters, StepAcknowledger, declare, run_node
from .markers import ObstacleMarkers


def supervisor_value_function(grid: Grid, speed: float, w_max: float, radius: float, horizon: float):
    """V_S from the lead's cached library solver when present, else solved here."""
    try:
        from ..reach.library import load_or_solve
    except ImportError:
        load_or_solve = None
    if load_or_solve is not None:
        return load_or_solve(grid, speed, w_max, radius, horizon)
    from ..reach.dynamics import DubinsCar
    from ..reach.sets import Disc
    from ..reach.solver import solve_avoid
    return solve_avoid(grid, DubinsCar(speed, w_max), Disc(0.0, 0.0, radius), horizon=horizon)


class SupervisorNode(Node):
    def __init__(self, node_name='supervisor', **kwargs):
        super().__init__(node_name, **kwargs)
        # its beliefs and noise take effect at run time (between games of a study: the
        # encounters start afresh); the grid of V_S and the robots watched are fixed
        p = lambda *a, **k: declare(self, *a, **k)  # noqa: E731
        ro = lambda *a, **k: declare(self, *a, read_only=True, **k)  # noqa: E731
        self.params = {
            'w_max': p('w_max', 0.75, "the supervisor's belief of the robots' turn-rate bound "
                       '[rad/s]; live (V_S is rebuilt)', 0.0, 20.0),
            'speed': p('speed', 3.0, "the supervisor's belief of the robots' speed [m/s]; live",
                       0.01, 100.0),
            'radius': p('radius', 1.8, "the supervisor's belief of the obstacle radius [m]; live",
                        0.01, 100.0),
            'horizon': p('horizon', 3.0, 'horizon of V_S [s]; live', 0.0, 100.0),
            'mu': p('mu', 0.5, 'intervention level mu of V_S; live', -100.0, 100.0),
            'sigma': p('sigma', 0.2, 'std of the per-approach noise w; live', 0.0, 100.0),
            'seed': p('seed', -1, 'random seed of the noise (-1: from the OS); live', -1, 2**31 - 1),
            'pending_timeout': p('pending_timeout', 5.0, 'sim seconds to wait for a removal before '
                                 'judging that obstacle again; live', 0.01, 1e4),
            'model': p('model', DEFAULT_MODEL, f"what an alarm V_S <= mu + w does, one of {', '.join(MODELS)}: "
                       'memoryless (the paper\'s) intervenes at once, attentive not while the robot\'s turns '
                       'away from that obstacle show it has seen it; live'),
            'convince_angle': p('convince_angle', 0.3, 'attentive: turn away from an obstacle (while it is the '
                                "robot's most urgent and it heads toward it) that convinces [rad]; live",
                                0.0, 10.0),
            'doubt_horizon': p('doubt_horizon', 0.5, 'attentive: a convinced belief is dropped when the straight '
                               'course enters the disc within this many seconds and the robot is not turning '
                               'away [s]; live', 0.0, 100.0),
            'doubt_window': p('doubt_window', 0.6, 'attentive: "turning away" is the net turn over this many '
                              'seconds [s]; live', 0.0, 100.0),
        }
        if self.params['model'] not in MODELS:
            self.get_logger().error(f"model {self.params['model']!r} is not one of {MODELS}; judging as "
                                    f'{DEFAULT_MODEL}')
            self.params['model'] = DEFAULT_MODEL
        half = ro('grid_half_width', 8.0, 'V_S grid spans +-this in x and y [m]', 1.0, 100.0)
        nxy = ro('grid_nxy', 65, 'V_S grid nodes per axis in x and y', 5, 1001)
        nth = ro('grid_ntheta', 42, 'V_S grid nodes in theta', 4, 720)
        self.robots = [r.strip('/') for r in ro('robots', ['robot_0'], 'robot namespaces to watch')]
        self.interventions_readers = ro(
            'interventions_readers', 0, 'ready for the lockstep clock only once /interventions has '
            'this many matched readers (a team: the world and the learner), so that no intervention '
            'of the first steps goes to a reader still being discovered', 0, 1000)

        self.grid = Grid((-half, -half), (half, half), (nxy, nxy, nth))
        self.vf = None
        self.watcher = None
        self.rebuild(set(self.params))
        self.live = LiveParameters(self, after=self.rebuild)
        for name in self.params:
            self.live.add(name, lambda v, name=name: self.params.__setitem__(name, v),
                          check=_check_model if name == 'model' else None)
        self.obstacles = ObstacleMarkers()
        self.intervention_pub = self.create_publisher(PoseStamped, '/interventions', rosmsg.QOS_EVENTS)
        self.decision_pub = self.create_publisher(DiagnosticStatus, '/supervisor/decisions',
                                                  rosmsg.QOS_LOG)
        self.acks = StepAcknowledger(
            self, self.robots,
            also_ready=lambda: self.intervention_pub.get_subscription_count() >= self.interventions_readers)
        self.create_subscription(MarkerArray, '/obstacle_markers', self.on_markers, rosmsg.QOS_LATCHED)
        for r in self.robots:
            self.acks.watch(self.create_subscription(
                PoseStamped, f'/{r}/pose', lambda m, r=r: self.on_pose(r, m), rosmsg.QOS_EVERY_SAMPLE))
        self.create_subscription(DiagnosticStatus, '/supervisor/reset', self.on_reset, rosmsg.QOS_EVENTS)
        self.get_logger().info(f'supervisor: watching {self.robots}')

    def rebuild(self, changed):
        """Put the parameters in force: V_S again if a belief changed, and a fresh watcher
        (new encounters, new draws) that keeps the removals already asked for."""
        q = self.params
        if self.vf is None or changed & {'w_max', 'speed', 'radius', 'horizon'}:
            self.vf = supervisor_value_function(self.grid, q['speed'], q['w_max'], q['radius'],
                                                q['horizon'])
        pending = dict(self.watcher.pending) if self.watcher is not None else {}
        attentive = AttentiveParams(**{k: float(q[k]) for k in AttentiveParams.__dataclass_fields__})
        self.watcher = Watcher(self.vf, mu=q['mu'], sigma=q['sigma'], pending_timeout=q['pending_timeout'],
                               seed=None if q['seed'] < 0 else q['seed'], model=q['model'],
                               attentive=attentive)
        self.watcher.pending = pending
        self.get_logger().info(f"supervisor: V_S with w_max={q['w_max']:.4g}, speed={q['speed']:.4g}, "
                               f"radius={q['radius']:.4g}, horizon={q['horizon']:.4g}; mu={q['mu']:.4g}, "
                               f"sigma={q['sigma']:.4g}, seed={q['seed']}, model={q['model']}")

    def on_reset(self, msg: DiagnosticStatus):
        """A new subject or game: these beliefs and noise, and no encounter or pending removal
        carried over (unlike a parameter change, which keeps the removals asked for)."""
        values = rosmsg.diagnostic_values(msg)
        try:
            new = {'mu': float(values.get('mu', self.params['mu'])),
                   'sigma': float(values.get('sigma', self.params['sigma'])),
                   'w_max': float(values.get('w_max', self.params['w_max'])),
                   'seed': int(values.get('seed', -1))}
            if not (0.0 <= new['w_max'] <= 20.0 and -1 <= new['seed'] <= 2**31 - 1
                    and new['sigma'] >= 0.0 and abs(new['mu']) <= 100.0):
                raise ValueError(f"w_max {new['w_max']}, sigma {new['sigma']}, mu {new['mu']} or "
                                 f"seed {new['seed']} out of range")
        except ValueError as exc:
            self.get_logger().error(f'/supervisor/reset rejected: {exc}; judging on unchanged')
            return
        changed = {k for k, v in new.items() if v != self.params[k]}
        self.params.update(new)
        self.watcher = None
        self.rebuild(changed)
        self.watcher.obstacles_changed(self.obstacles.arrays()[0])
        self.get_logger().info(f"supervisor reset: w_max={new['w_max']:.4g}, mu={new['mu']:.4g}, "
                               f"sigma={new['sigma']:.4g}, seed={new['seed']}")

    def on_markers(self, msg: MarkerArray):
        try:
            self.obstacles.update(msg)
        except ValueError as exc:
            self.get_logger().error(f'/obstacle_markers rejected: {exc}')
            return
        self.watcher.obstacles_changed(self.obstacles.arrays()[0])

    def on_pose(self, robot, msg: PoseStamped):
        try:
            self.judge(robot, msg)
        finally:
            self.acks.processed(robot, msg.header.stamp)   # after any intervention went out

    def judge(self, robot, msg: PoseStamped):
        try:
            state = rosmsg.pose_to_state(msg)
        except rosmsg.MessageError as exc:
            self.get_logger().error(f'pose of {robot} rejected: {exc}', throttle_duration_sec=1.0)
            return
        t = Time.from_msg(msg.header.stamp).nanoseconds * 1e-9
        ids, xy = self.obstacles.arrays()
        decision = self.watcher.judge(robot, state, t, ids, xy)
        if decision is None:
            return
        stamp = Time(nanoseconds=int(round(decision.time * 1e9))).to_msg()
        out = rosmsg.state_to_pose(decision.rel_state, stamp, rosmsg.obstacle_frame(decision.obstacle_id))
        self.intervention_pub.publish(out)
        values = {'robot': robot, 'obstacle': decision.obstacle_id, 'time': f'{decision.time:.4f}',
                  'value': f'{decision.value:.4f}', 'threshold': f'{decision.threshold:.4f}'}
        values.update({k: self.params[k] for k in ('w_max', 'mu', 'sigma', 'horizon', 'radius', 'model')})
        self.decision_pub.publish(rosmsg.make_diagnostic('intervention', values))
        # the world's INFO line tells the story of each intervention; this is the detail
        self.get_logger().debug(f'intervene: {robot} at V_S={decision.value:.3f} <= '
                                f'{decision.threshold:.3f} near obstacle {decision.obstacle_id}')


def _check_model(value):
    """None if ``value`` is a supervisor model, else the reason to refuse it."""
    return None if value in MODELS else f"unknown model; one of {', '.join(MODELS)}"


def main(args=None):
    return run_node(SupervisorNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
