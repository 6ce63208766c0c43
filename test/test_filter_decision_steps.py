"""docs/filter_learner.md "How a decision is made" names only steps that exist: every
``path:function`` it lists is a file of the repository defining that function or class, and
the steps ``decide.step_many`` runs appear in it in the order it runs them."""
import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def steps() -> list:
    text = (ROOT / 'docs' / 'filter_learner.md').read_text()
    section = text.split('## How a decision is made', 1)[1].split('\n## ', 1)[0]
    return re.findall(r'^\d+\. `([\w/]+\.py):(\w+)`', section, flags=re.M)


def defined(path: Path) -> set:
    tree = ast.parse(path.read_text())
    return {n.name for n in tree.body if isinstance(n, (ast.FunctionDef, ast.ClassDef))}


def test_every_step_names_a_function_that_exists():
    named = steps()
    assert len(named) >= 10, named
    for path, name in named:
        assert (ROOT / path).is_file(), path
        assert name in defined(ROOT / path), f'{path} defines no {name}'


def test_the_steps_of_step_many_are_listed_in_the_order_it_runs_them():
    """The calls in ``step_many``'s body, in order, are the section's steps in order."""
    source = (ROOT / 'supersafe_ros' / 'filter' / 'decide.py').read_text()
    body = next(n for n in ast.parse(source).body if isinstance(n, ast.FunctionDef) and n.name == 'step_many')
    calls = [n for n in ast.walk(body) if isinstance(n, ast.Call) and isinstance(n.func, ast.Name)]
    called = [n.func.id for n in sorted(calls, key=lambda n: (n.lineno, n.col_offset))]
    listed = [name for _, name in steps()]
    in_both = [c for c in dict.fromkeys(called) if c in listed]
    assert {'gather', 'constraint_rows', 'decide_rows', 'outputs', 'record'} <= set(in_both), in_both
    assert in_both == sorted(in_both, key=listed.index), (in_both, listed)
