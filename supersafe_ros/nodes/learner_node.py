"""learner_node: learns the supervisor's safe set from interventions, online.

Topics and services:
  sub  /interventions            geometry_msgs/PoseStamped   the intervened robot's pose in the
                                                             removed obstacle's frame (obstacle at the
                                                             origin, axes as map); frame_id
                                                             obstacle_<id>; stamp = intervention time
  pub  /safe_set/value_function  std_msgs/Float32MultiArray  latched: the fitted V, exact float32,
                                                             with grid and fit as JSON (supersafe_ros.ros_io.vfmsg)
  pub  /safe_set/fit             diagnostic_msgs/DiagnosticStatus  latched: omega_max, mu, sigma,
                                                             alpha, interventions, log_likelihood,
                                                             estimator (+ index, store, notes)
  srv  ~/reset                   std_srvs/Empty              new subject: archive the data file
                                                             (renamed, never deleted), start empty,
                                                             publish the standard set

Every intervention is validated (finite, frame naming an obstacle, normalisable
quaternion, inside the library's grid, not a duplicate of a stored one), then
appended to the store and fsynced *before* anything else, then the library is
refitted (``learning.estimators.fit_paper``: the paper's estimator, with the
conservative prior by default) and the fit published once ``min_interventions``
are stored. On start the store is reloaded and the fit republished if data exist.
"""
from __future__ import annotations

import math
import os
import time

from rclpy.node import Node

from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from std_msgs.msg import Float32MultiArray
from std_srvs.srv import Empty

from ..ros_io import rosmsg
from ..learning.intervention_store import Intervention, InterventionStore
# imported here, not in the first refit: scipy takes ~1 s to import on a busy machine
from ..learning.estimators import fit_paper
from ..reach.library import PAPER_OMEGAS, LibrarySpec, load_or_build_library
from ..ros_io.vfmsg import value_function_to_msg
from .common import declare, run_node

VALUE_FUNCTION_TOPIC = '/safe_set/value_function'
FIT_TOPIC = '/safe_set/fit'
ESTIMATORS = ('paper',)   # first-passage needs whole encounters; /interventions carries states only
DEFAULT_OMEGAS = [float(w) for w in PAPER_OMEGAS]


def default_store_path() -> str:
    base = os.environ.get('XDG_DATA_HOME') or os.path.expanduser('~/.local/share')
    return os.path.join(base, 'supersafe_ros', 'interventions.jsonl')


def build_library(speed, radius, horizon, omegas, lo, hi, shape, cache_dir=None):
    """The candidate value functions sorted by omega_max (from the cache, or solved and cached)."""
    spec = LibrarySpec(speed=speed, radius=radius, omegas=tuple(sorted(omegas)),
                       horizon=horizon if horizon > 0 else None, lo=tuple(lo), hi=tuple(hi),
                       shape=tuple(int(n) for n in shape))
    return list(load_or_build_library(spec, cache_dir=cache_dir or None).entries)


class LearnerNode(Node):
    def __init__(self, node_name='learner', **kwargs):
        super().__init__(node_name, **kwargs)
        p = lambda *a, **k: declare(self, *a, **k)  # noqa: E731
        store_path = p('store_path', '', 'JSON-lines file of accepted interventions, one per subject '
                       '("" = $XDG_DATA_HOME or ~/.local/share, supersafe_ros/interventions.jsonl)')
        store_path = store_path or default_store_path()
        self.estimator = p('estimator', 'paper', f'estimator, one of {ESTIMATORS}')
        if self.estimator not in ESTIMATORS:
            raise ValueError(f"estimator '{self.estimator}' is not one of {ESTIMATORS}")
        self.alpha_k = p('alpha_k', 0.0, 'alpha = mu + alpha_k sigma (paper: 0)', -5.0, 10.0)
        self.min_interventions = p('min_interventions', 3, 'interventions stored before a fit is '
                                   'published (fewer give a degenerate sigma)', 1, 100000)
        self.prior = p('conservative_prior', True, 'only entries whose unsafe set contains the true '
                       'one (true_omega_max) are admissible (paper, MAP prior)')
        true_omega = p('true_omega_max', 1.0, 'robots\' true turn-rate bound [rad/s] (prior, reset)',
                       0.0, 20.0)
        self.frame_prefix = p('obstacle_frame_prefix', rosmsg.OBSTACLE_FRAME_PREFIX,
                              'an intervention frame must start with this ("" = any non-empty frame)')
        speed = p('library_speed', 3.0, 'library: robot speed [m/s]', 0.01, 100.0)
        radius = p('library_radius', 1.8, 'library: obstacle radius [m]', 0.01, 100.0)
        horizon = p('library_horizon', 3.0, 'library: avoid horizon [s] (0 = to convergence)', 0.0, 1000.0)
        omegas = p('library_omegas', DEFAULT_OMEGAS, 'library: candidate turn-rate bounds [rad/s]')
        self.lo = p('library_lo', [-8.0, -8.0], 'library grid: (xmin, ymin) [m]')
        self.hi = p('library_hi', [8.0, 8.0], 'library grid: (xmax, ymax) [m]')
        shape = p('library_shape', [65, 65, 42], 'library grid: nodes (nx, ny, ntheta)')
        cache_dir = p('cache_dir', '', 'library cache ("" = $SUPERSAFE_CACHE or ~/.cache/supersafe_ros)')

        t0 = time.perf_counter()
        self.entries = build_library(speed, radius, horizon, omegas, self.lo, self.hi, shape, cache_dir)
        self.true_vf = self._true_entry(true_omega)
        self.get_logger().info(f'library of {len(self.entries)} entries {tuple(shape)} ready in '
                               f'{time.perf_counter() - t0:.2f} s')

        self.vf_pub = self.create_publisher(Float32MultiArray, VALUE_FUNCTION_TOPIC, rosmsg.QOS_LATCHED)
        self.fit_pub = self.create_publisher(DiagnosticStatus, FIT_TOPIC, rosmsg.QOS_LATCHED)
        self.create_subscription(PoseStamped, '/interventions', self.on_intervention, rosmsg.QOS_EVENTS)
        self.create_service(Empty, '~/reset', self.on_reset)

        self.store = InterventionStore(store_path)
        self.fit = None
        self.rejected = 0
        self.timing = {}   # seconds spent on the last store append, fit, value-function publish
        msg = f'store {self.store.path}: {len(self.store)} interventions'
        if self.store.torn_bytes:
            msg += f', cut a torn last line of {self.store.torn_bytes} bytes'
        if self.store.skipped_lines:
            msg += f', skipped {self.store.skipped_lines} damaged lines'
        self.get_logger().info(msg)
        if len(self.store) >= self.min_interventions:
            self.refit('restart')

    def _true_entry(self, omega):
        """The library entry of the true dynamics (conservative prior, reset set)."""
        for e in self.entries:
            if e.meta.get('omega_max') is not None and abs(float(e.meta['omega_max']) - omega) < 1e-9:
                return e
        raise ValueError(f'true_omega_max {omega} is not among the library omegas '
                         f'{[e.meta.get("omega_max") for e in self.entries]}')

    def close(self):
        self.store.close()

    # -- interventions ---------------------------------------------------------------------
    def parse(self, msg: PoseStamped) -> Intervention:
        """Validated intervention; raises ValueError with the reason."""
        frame = msg.header.frame_id
        if not frame:
            raise ValueError('frame_id is empty (it must name the removed obstacle)')
        if self.frame_prefix and not frame.startswith(self.frame_prefix):
            raise ValueError(f"frame '{frame}' does not name an obstacle ('{self.frame_prefix}<id>')")
        x, y, theta = rosmsg.pose_to_state(msg, frame=None)
        if not (self.lo[0] <= x <= self.hi[0] and self.lo[1] <= y <= self.hi[1]):
            raise ValueError(f'state ({x:.3g}, {y:.3g}) is outside the library grid '
                             f'{tuple(self.lo)}..{tuple(self.hi)}')
        stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        if stamp_ns == 0:   # unstamped: use the arrival time (duplicates then cannot be told apart)
            stamp_ns = self.get_clock().now().nanoseconds
        return Intervention(int(stamp_ns), frame, x, y, theta, time.time())

    def on_intervention(self, msg: PoseStamped):
        self.timing['received_monotonic_ns'] = time.monotonic_ns()   # for latency breakdowns
        try:
            entry = self.parse(msg)
        except ValueError as exc:
            self.rejected += 1
            self.get_logger().error(f'intervention rejected: {exc}')
            self.publish_status(f'intervention rejected: {exc}', level=1)
            return
        t0 = time.perf_counter()
        stored = self.store.append(entry)   # persisted (fsync) before anything else
        self.timing['store_s'] = time.perf_counter() - t0
        if not stored:
            self.get_logger().warn(f'duplicate intervention ({entry.frame}, stamp {entry.stamp_ns}) ignored')
            return
        self.get_logger().info(f'intervention {len(self.store)} stored: {entry.frame} at '
                               f'({entry.x:.2f}, {entry.y:.2f}, {entry.theta:.2f})')
        if len(self.store) >= self.min_interventions:
            self.refit('intervention')
        else:
            self.publish_status(f'{len(self.store)} of {self.min_interventions} interventions needed '
                                'before a fit', level=0)

    # -- fit ------------------------------------------------------------------------------------
    def refit(self, why: str):
        t0 = time.perf_counter()
        try:
            fit = fit_paper(self.entries, self.store.states(),
                            true_vf=self.true_vf if self.prior else None, alpha_k=self.alpha_k)
        except ValueError as exc:
            self.get_logger().error(f'fit failed ({why}): {exc}; keeping the previous fit')
            self.publish_status(f'fit failed: {exc}', level=2)
            return None
        self.fit = fit
        self.timing['fit_s'] = time.perf_counter() - t0
        summary = {k: v for k, v in fit.to_dict().items() if k != 'candidates'}
        extra = dict(summary, source='learned', alpha_k=self.alpha_k, conservative_prior=self.prior,
                     stamp_ns=self.get_clock().now().nanoseconds)
        extra.pop('notes', None)
        self.vf_pub.publish(value_function_to_msg(fit.value_function, **extra))
        self.timing['publish_s'] = time.perf_counter() - t0 - self.timing['fit_s']
        self.publish_status(f'fit on {fit.interventions} interventions ({why}) in '
                            f'{time.perf_counter() - t0:.3f} s', level=1 if fit.notes else 0)
        self.get_logger().info(f'fit ({why}): omega_max {fit.omega_max:g}, mu {fit.mu:.4g}, '
                               f'sigma {fit.sigma:.4g}, alpha {fit.alpha:.4g}, '
                               f'{fit.interventions} interventions')
        return fit

    def publish_status(self, message: str, level: int = 0):
        f = self.fit
        nan = math.nan
        values = {
            'omega_max': f.omega_max if f else nan, 'mu': f.mu if f else nan,
            'sigma': f.sigma if f else nan, 'alpha': f.alpha if f else nan,
            'interventions': len(self.store), 'log_likelihood': f.log_likelihood if f else nan,
            'estimator': self.estimator, 'fitted_interventions': f.interventions if f else 0,
            'index': f.index if f else -1, 'store': self.store.path,
            'rejected': self.rejected, 'notes': '; '.join(f.notes) if f else '',
        }
        values.update({k: (str(v) if isinstance(v, int) else f'{v:.6f}') for k, v in self.timing.items()})
        self.fit_pub.publish(rosmsg.make_diagnostic('learner', values, message, level))

    # -- reset ---------------------------------------------------------------------------------
    def on_reset(self, request, response):
        archived = self.store.archive()
        self.fit = None
        self.get_logger().info(f'reset for a new subject: data archived to {archived or "(nothing)"}; '
                               'publishing the standard set')
        self.vf_pub.publish(value_function_to_msg(self.true_vf, source='standard', alpha=0.0,
                                                  interventions=0, estimator=self.estimator,
                                                  stamp_ns=self.get_clock().now().nanoseconds))
        self.publish_status(f'reset: no data (previous archived to {archived or "nothing"})', level=0)
        return response


def main(args=None):
    try:
        return run_node(LearnerNode, args)
    except KeyboardInterrupt:   # a Ctrl-C that lands during shutdown: data are fsynced already
        return 0


if __name__ == '__main__':
    raise SystemExit(main())
