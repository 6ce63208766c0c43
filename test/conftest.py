"""Test session set-up shared by every test module.

* DDS stays on loopback and the session gets its own ROS_DOMAIN_ID, set here
  before any test imports rclpy, so runs on one machine cannot hear each other.
* Value functions are cached under .cache/test-values in the repository (or
  $SUPERSAFE_CACHE), so solving happens once per machine, not once per test.
* ``ros_context``: each topic-level test module runs its nodes in its own rclpy
  Context (rclpy is imported only when a test asks for it); the plumbing that spins
  them is in graph_support.py.
* Markers (declared in setup.cfg, ``--strict-markers``): ``ros`` (starts rclpy nodes in
  this process or node processes), ``browser`` (headless Chromium), ``root`` (network
  namespaces), ``slow`` (over ~20 s alone). ``pytest -m "not ros and not browser"`` runs
  the fast ROS-free core; a test that takes ``ros_context`` without ``ros`` is refused.
"""
import os
from pathlib import Path

import pytest

from supersafe_ros.rosenv import ensure_local_ros_env

REPO = Path(__file__).resolve().parents[1]
S3_DATA = REPO.parent / 'shared' / 'data' / 's3'

ensure_local_ros_env()
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
if 'SUPERSAFE_TEST_DOMAIN_SET' not in os.environ:
    # 110..199: clear of the default domain 0 and of the developer shell's domain
    os.environ['ROS_DOMAIN_ID'] = str(110 + os.getpid() % 90)
    os.environ['SUPERSAFE_TEST_DOMAIN_SET'] = '1'
os.environ.setdefault('SUPERSAFE_CACHE', str(REPO / '.cache' / 'test-values'))
os.environ.setdefault('ROS_LOG_DIR', str(REPO / '.cache' / 'ros-log'))


@pytest.fixture(scope='session')
def s3_data() -> Path:
    """The paper's own data (../shared/data/s3), or a skip saying where it was looked for."""
    if not S3_DATA.is_dir():
        pytest.skip(f'missing data: the paper\'s S3 files (*_reachset.json, pilot*_interventions.csv) '
                    f'at {S3_DATA}; put the shared/ folder beside the repository')
    return S3_DATA


@pytest.fixture(params=['alone', 'beside an idle robot'])
def decision_path(request, monkeypatch):
    """Run a test's ``RobotFilter.step`` calls through each path of ``step_many``: a robot alone
    takes the one-robot path (``gather.gather_one_fast``, Python scalars); beside a robot with no inputs
    (left out of the law: it only gets the fail safe) it takes the vectorised path. Every
    single-robot expectation then holds for both."""
    from supersafe_ros.filter import RobotFilter, step_many
    if request.param != 'alone':
        def step_beside_idle(self, safe_set, t, clusters=None):
            return step_many([self, RobotFilter(self.config)], safe_set, t, clusters)[0]
        monkeypatch.setattr(RobotFilter, 'step', step_beside_idle)
    return request.param


@pytest.fixture(scope='module')
def ros_context(tmp_path_factory):
    """An rclpy Context of the test module's own, initialised on loopback and shut down after it."""
    ensure_local_ros_env()
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ.setdefault('SUPERSAFE_CACHE', str(tmp_path_factory.getbasetemp() / 'vf-cache'))
    import rclpy
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    yield ctx
    ctx.try_shutdown()


def pytest_collection_modifyitems(config, items):
    """Refuse a test that starts rclpy nodes (it takes ``ros_context``) but is not marked ``ros``:
    ``-m "not ros"`` must leave no node behind."""
    unmarked = [item.nodeid for item in items
                if 'ros_context' in getattr(item, 'fixturenames', ()) and item.get_closest_marker('ros') is None]
    if unmarked:
        raise pytest.UsageError('tests that take ros_context must be marked ros (pytest.mark.ros):\n  '
                                + '\n  '.join(unmarked))
