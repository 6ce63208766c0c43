"""The package's import graph has no cycle, and no module outgrows a newcomer's reading.

The graph is read from the source with ``ast`` (nothing is imported): every ``import``
and ``from ... import`` anywhere in a module, at module level or inside a function,
relative or absolute. ``from pkg import name`` is an edge to ``pkg.name`` when that is
a module of the package, else to ``pkg``. Importing ``a.b.c`` also runs ``a/__init__``
and ``a/b/__init__``; those implicit edges are left out (a package's ``__init__`` may
name its submodules without making a cycle with each of them).

A cycle is a strongly connected component of more than one module (Tarjan); the
failure names each one, with one cycle through it and the import lines that close it.
"""
from __future__ import annotations

import ast
from collections import deque
from pathlib import Path


REPO = Path(__file__).resolve().parents[1]
PACKAGE_DIR = REPO / 'supersafe_ros'
MAX_LINES = 600


def module_files(package_dir: Path) -> dict[str, Path]:
    """Dotted module name -> file, for every .py under ``package_dir`` (a package's
    ``__init__.py`` is the package's own name)."""
    out = {}
    for path in sorted(package_dir.rglob('*.py')):
        parts = list(path.relative_to(package_dir.parent).with_suffix('').parts)
        if parts[-1] == '__init__':
            parts.pop()
        out['.'.join(parts)] = path
    return out


def _imported(module: str, is_package: bool, node, modules) -> list[str]:
    """The package's modules one import statement names (see the module docstring)."""
    if isinstance(node, ast.Import):
        targets = []
        for alias in node.names:
            # `import a.b.c` binds the package `a` but loads a.b.c: the deepest module named
            name = alias.name
            while name and name not in modules:
                name = name.rpartition('.')[0]
            if name:
                targets.append(name)
        return targets
    if node.level:
        base = module.split('.') if is_package else module.split('.')[:-1]
        base = base[:len(base) - (node.level - 1)]
        source = '.'.join(base + ([node.module] if node.module else []))
    else:
        source = node.module or ''
    targets = []
    for alias in node.names:
        sub = f'{source}.{alias.name}'
        if sub in modules:
            targets.append(sub)
        elif source in modules:
            targets.append(source)
    return targets


def import_graph(package_dir: Path = PACKAGE_DIR) -> dict[str, dict[str, int]]:
    """module -> {imported module: line of the first import of it}, within the package."""
    modules = module_files(package_dir)
    graph = {}
    for module, path in modules.items():
        edges: dict[str, int] = {}
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in ast.walk(tree):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                for target in _imported(module, path.name == '__init__.py', node, modules):
                    if target != module:      # `from . import NAME` in an __init__: itself
                        edges.setdefault(target, node.lineno)
        graph[module] = edges
    return graph


def strongly_connected(graph: dict) -> list[list[str]]:
    """Tarjan's strongly connected components (iterative: no recursion limit)."""
    index, low, on_stack, stack, out = {}, {}, set(), [], []
    counter = 0
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(graph[root]))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            for child in children:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(graph[child])))
                    break
                if child in on_stack:
                    low[node] = min(low[node], index[child])
            else:
                work.pop()
                if work:
                    parent = work[-1][0]
                    low[parent] = min(low[parent], low[node])
                if low[node] == index[node]:
                    component = []
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        component.append(member)
                        if member == node:
                            break
                    out.append(sorted(component))
    return out


def cycles(graph: dict) -> list[list[str]]:
    """Every strongly connected component of more than one module."""
    return [c for c in strongly_connected(graph) if len(c) > 1]


def shortest_cycle(graph: dict, component: list[str]) -> list[str]:
    """One shortest cycle through the component's first module (BFS inside the component)."""
    start, members = component[0], set(component)
    previous = {start: None}
    queue = deque([start])
    while queue:
        node = queue.popleft()
        for child in graph[node]:
            if child == start:
                path = [node]
                while previous[path[-1]] is not None:
                    path.append(previous[path[-1]])
                return path[::-1] + [start]
            if child in members and child not in previous:
                previous[child] = node
                queue.append(child)
    return [start, start]


def describe(graph: dict, cycle: list[str]) -> str:
    """'a (line 12) -> b (line 40) -> a': each arrow is the import line in the module before it."""
    steps = [cycle[0]]
    for a, b in zip(cycle, cycle[1:]):
        steps.append(f'(line {graph[a][b]}) -> {b}')
    return ' '.join(steps)


def long_modules(package_dir: Path = PACKAGE_DIR, limit: int = MAX_LINES) -> dict[str, int]:
    """Path (relative to the repository) -> line count of every module over ``limit`` lines."""
    out = {}
    for path in module_files(package_dir).values():
        n = len(path.read_text().splitlines())
        if n > limit:
            out[path.relative_to(package_dir.parent).as_posix()] = n
    return out


# -- the rules on this tree --------------------------------------------------------------
def test_the_package_has_no_import_cycle():
    graph = import_graph()
    found = cycles(graph)
    assert not found, 'import cycles (each a strongly connected component; one cycle shown):\n' + '\n'.join(
        f'  {{{", ".join(c)}}}: {describe(graph, shortest_cycle(graph, c))}' for c in found)


def test_no_module_is_over_600_lines():
    over = long_modules()
    assert not over, f'modules over {MAX_LINES} lines: {over}'


# -- the rules themselves, on small trees --------------------------------------------------
def _tree(tmp_path, files: dict) -> Path:
    for name, text in files.items():
        path = tmp_path / 'pkg' / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return tmp_path / 'pkg'


def test_a_cycle_through_a_function_level_import_is_found(tmp_path):
    pkg = _tree(tmp_path, {
        '__init__.py': '',
        'a.py': 'from .b import f\n',
        'b.py': 'def f():\n    from . import a\n',
        'c.py': 'import pkg.a\n',
    })
    graph = import_graph(pkg)
    assert graph['pkg.b'] == {'pkg.a': 2}
    assert cycles(graph) == [['pkg.a', 'pkg.b']]
    assert describe(graph, shortest_cycle(graph, ['pkg.a', 'pkg.b'])) == \
        'pkg.a (line 1) -> pkg.b (line 2) -> pkg.a'


def test_names_resolve_to_modules_or_their_package_and_init_is_implicit(tmp_path):
    pkg = _tree(tmp_path, {
        '__init__.py': 'from .sub.x import X\n',       # the package names its submodule: no cycle
        'sub/__init__.py': 'NAME = 1\n',
        'sub/x.py': 'from .. import sub\nX = 1\n',      # `sub` is a module (the package)
        'y.py': 'from .sub import NAME, x\nfrom pkg.sub.x import X\nimport pkg.sub.x as sx\n',
    })
    graph = import_graph(pkg)
    assert graph['pkg.y'] == {'pkg.sub': 1, 'pkg.sub.x': 1}
    assert graph['pkg.sub.x'] == {'pkg.sub': 1}
    assert graph['pkg'] == {'pkg.sub.x': 1}
    assert cycles(graph) == []


def test_a_module_over_the_limit_is_named(tmp_path):
    pkg = _tree(tmp_path, {'__init__.py': '', 'long.py': 'x = 1\n' * 601, 'ok.py': 'x = 1\n' * 600})
    assert long_modules(pkg) == {'pkg/long.py': 601}
