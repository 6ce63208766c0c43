"""docs/filter_learner.md "How a decision is made" names only steps that exist: every
``path:function`` it lists is a file of the repository defining that function or class, and
the steps ``decide.step_many`` runs (``decide_many``'s: ``gather``, then ``decide``'s; then the
record) appear in it in the order it runs them."""
import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def section() -> str:
    text = (ROOT / 'docs' / 'filter_learner.md').read_text()
    return text.split('## How a decision is made', 1)[1].split('\n## ', 1)[0]


def listed_in(text: str) -> list:
    return re.findall(r'^\d+\. `([\w/]+\.py):(\w+)`', text, flags=re.M)


def steps() -> list:
    """The decision's steps (the section's first list)."""
    return listed_in(section().split('\n### ', 1)[0])


def node_steps() -> list:
    """The node's steps around it ("The node around it")."""
    return listed_in(section().split('\n### The node around it', 1)[1])


def defined(path: Path) -> set:
    tree = ast.parse(path.read_text())
    return {n.name for n in tree.body if isinstance(n, (ast.FunctionDef, ast.ClassDef))}


def test_every_step_names_a_function_that_exists():
    named = steps() + node_steps()
    assert len(steps()) >= 10 and len(node_steps()) >= 5, named
    for path, name in named:
        assert (ROOT / path).is_file(), path
        assert name in defined(ROOT / path), f'{path} defines no {name}'


def calls_of(name: str) -> list:
    """The names called in ``decide.<name>``'s body, in order, a call of ``decide_many`` or ``decide``
    expanded."""
    source = (ROOT / 'supersafe_ros' / 'filter' / 'decide.py').read_text()
    body = next(n for n in ast.parse(source).body if isinstance(n, ast.FunctionDef) and n.name == name)
    calls = [n for n in ast.walk(body) if isinstance(n, ast.Call) and isinstance(n.func, ast.Name)]
    called = [n.func.id for n in sorted(calls, key=lambda n: (n.lineno, n.col_offset))]
    return [c for called_name in called for c in ([called_name, *calls_of(called_name)]
                                                  if called_name in ('decide_many', 'decide') else [called_name])]


def test_the_steps_of_step_many_are_listed_in_the_order_it_runs_them():
    """The calls in ``step_many``'s body (``decide_many``'s and ``decide``'s, then the record), in
    order, are the section's steps in order."""
    called = calls_of('step_many')
    listed = [name for _, name in steps()]
    in_both = [c for c in dict.fromkeys(called) if c in listed]
    assert {'decide_many', 'gather', 'decide', 'constraint_rows', 'choose', 'avoid_turns', 'command', 'outputs',
            'record_decisions'} <= set(in_both), in_both
    assert in_both == sorted(in_both, key=listed.index), (in_both, listed)


def method_calls(path: str, cls: str, method: str) -> list:
    """The names called in ``cls.method``'s body (``f(...)``, ``x.f(...)``), in the order written."""
    tree = ast.parse((ROOT / path).read_text())
    klass = next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == cls)
    body = next(n for n in klass.body if isinstance(n, ast.FunctionDef) and n.name == method)
    calls = sorted((n for n in ast.walk(body) if isinstance(n, ast.Call)), key=lambda n: (n.lineno, n.col_offset))
    return [c.func.id if isinstance(c.func, ast.Name) else c.func.attr for c in calls
            if isinstance(c.func, (ast.Name, ast.Attribute))]


def in_order(called, wanted) -> bool:
    """``wanted`` appears in ``called`` in that order (others between)."""
    it = iter(called)
    return all(any(c == w for c in it) for w in wanted)


def test_the_node_half_runs_in_the_order_listed():
    """safety_filter_node (the one filter node): a pose is read by its Source, then taken by the
    filter, then decided; a decision is made, judged by the lockstep policy, sent through each
    robot's topics, recorded, told, and its states said, in that order; a tick takes every robot's
    inputs before it decides them."""
    names = [name for _, name in node_steps()]
    assert names[:2] == ['PoseSource', 'RobotFilter'] and 'decide_many' in names
    node = 'supersafe_ros/nodes/safety_filter_node.py'
    assert in_order(method_calls(node, 'SafetyFilter', 'take_pose'), ['read', 'update_pose'])
    assert in_order(method_calls(node, 'SafetyFilter', 'on_pose'), ['take_pose', 'decide'])
    assert in_order(method_calls(node, 'SafetyFilter', 'on_command'), ['take_command', 'decide'])
    decide = method_calls(node, 'SafetyFilter', 'decide')
    assert in_order(decide, ['decide_many', 'judge', '_send', 'record_decisions', '_after']), decide
    assert 'send' in method_calls(node, 'SafetyFilter', '_send')
    assert 'cmd_vel' in method_calls('supersafe_ros/nodes/filter_topics.py', 'RobotTopics', 'send')
    assert in_order(method_calls(node, 'SafetyFilter', '_after'), ['tell', 'due', '_say_states'])
    assert 'state_message' in method_calls(node, 'SafetyFilter', '_say_states')
    tick = method_calls(node, 'SafetyFilter', 'decide_all')
    assert in_order(tick, ['_take_batched', 'take', 'taker', 'decide']), tick
