"""flake8 over the package, its tests, the benchmarks, the launch file and setup.py, as ament packages run it.

ament_flake8 (ros2/examples' test_flake8.py) with this house's configuration: the
``[flake8]`` section of setup.cfg (pyflakes and pycodestyle at width 120; its comments
say what is ignored and why), given with ``--config``. ``pytest -m flake8 test`` runs it alone.
"""
from pathlib import Path

from ament_flake8.main import main_with_errors
import pytest

REPO = Path(__file__).resolve().parents[1]
PATHS = ['supersafe_ros', 'test', 'bench', 'launch', 'setup.py']


@pytest.mark.flake8
@pytest.mark.linter
def test_flake8(monkeypatch):
    monkeypatch.chdir(REPO)     # ament_flake8 walks the working directory for AMENT_IGNORE
    rc, errors = main_with_errors(argv=['--config', str(REPO / 'setup.cfg'), *PATHS])
    assert rc == 0, \
        'Found %d code style errors / warnings:\n' % len(errors) + \
        '\n'.join(errors)
