"""Docstrings checked by ament_pep257 (pydocstyle), as ament packages run it, in this house's convention.

ament_pep257's default convention ignores D100-D107, D203, D212 and D404 and checks
everything else; on this code that flags ~2,000 docstrings, nearly all for one house
style (hj_reachability's): a summary sentence that starts on the first line and may
wrap. So the checks ignored here (``IGNORE``) are ament's, with D212 checked instead of
D213, plus the rules that style breaks on purpose:

* D213 (summary on the second line): the summary starts on the first line; D212, which
  asks for that, is checked;
* D205, D400, D415 (one-line summary, then a blank line; ending with a period): the
  summary sentence may wrap over several lines;
* D209 (closing quotes on a line of their own): they may end the last line of text;
* D401 (imperative mood): summaries describe ("The avoid solver ...");
* D402, D403 (no signature in the first line; first word capitalised): a summary may
  begin with a symbol or an identifier (``mu``, ``argv``, ``ValueFunction``), and
  pydocstyle, which drops spaces, reads "states (x, y, theta)" as the signature of ``states``.

Still checked, and kept by the code: the docstring's whitespace and layout (D200-D202,
D204, D206-D208, D210-D212, D214, D215: one-liners on one line, no blank lines around a
function's docstring, indentation, no padding inside the quotes), its quoting (D300
triple double quotes, D301 r-prefix with backslashes) and the section rules (D405-D419).
``pytest -m pep257 test`` runs it alone.
"""
from pathlib import Path

from ament_pep257.main import main
import pytest

REPO = Path(__file__).resolve().parents[1]
PATHS = ['supersafe_ros', 'test', 'bench', 'launch', 'setup.py']
IGNORE = ['D100', 'D101', 'D102', 'D103', 'D104', 'D105', 'D106', 'D107', 'D203', 'D404',   # ament's
          'D205', 'D209', 'D213', 'D400', 'D401', 'D402', 'D403', 'D415']                  # this house's


@pytest.mark.linter
@pytest.mark.pep257
def test_pep257(monkeypatch):
    monkeypatch.chdir(REPO)
    rc = main(argv=['--ignore', *IGNORE, '--', *PATHS])
    assert rc == 0, 'Found code style errors / warnings'
