"""docs/filter_learner.md "How a decision is made" names only steps that exist: every
``path:function`` it lists is a file of the repository defining that function or class, and
the steps ``decide.step_many`` runs (``decide_many``'s, then the record) appear in it in the order
it runs them."""
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


def calls_of(name: str) -> list:
    """The names called in ``decide.<name>``'s body, in order, a call of ``decide_many`` expanded."""
    source = (ROOT / 'supersafe_ros' / 'filter' / 'decide.py').read_text()
    body = next(n for n in ast.parse(source).body if isinstance(n, ast.FunctionDef) and n.name == name)
    calls = [n for n in ast.walk(body) if isinstance(n, ast.Call) and isinstance(n.func, ast.Name)]
    called = [n.func.id for n in sorted(calls, key=lambda n: (n.lineno, n.col_offset))]
    return [c for called_name in called for c in ([called_name, *calls_of(called_name)]
                                                  if called_name == 'decide_many' else [called_name])]


def test_the_steps_of_step_many_are_listed_in_the_order_it_runs_them():
    """The calls in ``step_many``'s body (``decide_many``'s, then the record), in order, are the
    section's steps in order."""
    called = calls_of('step_many')
    listed = [name for _, name in steps()]
    in_both = [c for c in dict.fromkeys(called) if c in listed]
    assert {'decide_many', 'gather', 'constraint_rows', 'decide_rows', 'outputs', 'record_decisions'} <= set(in_both), \
        in_both
    assert in_both == sorted(in_both, key=listed.index), (in_both, listed)
