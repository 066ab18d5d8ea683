"""The import graph of src/ and bench/: no cycles between modules, and no import upwards across
layers.

Layers, lowest first (docs/architecture.md): the core (gsp_kinematics), the message layer
(gsp_msgs_py), the nodes (gsp_platform_sim, gsp_platform_bridge, gsp_device_driver, and
gsp_calibrator's node side), the user tools (gsp_calibrator.tools), the benchmark and paper
reproduction (bench/gsp_bench, no package). A module may import its own layer or lower ones,
never a higher one.
"""

import ast
from pathlib import Path

import pytest

WS = Path(__file__).resolve().parents[1]
SRC = WS / 'src'
BENCH = WS / 'bench'

#: Layer of each top-level package or subpackage; the longest matching prefix wins.
LAYERS = {
    'gsp_kinematics': 0,
    'gsp_msgs_py': 1,
    'gsp_platform_sim': 2,
    'gsp_platform_bridge': 2,
    'gsp_device_driver': 2,
    'gsp_calibrator': 2,
    'gsp_calibrator.tools': 3,
    'gsp_bench': 4,
}
LAYER_NAMES = ('core', 'message layer', 'nodes', 'tools', 'bench')


def module_files(src=SRC, pattern='*/gsp_*'):
    """Module name -> source file of every package module under `src` (tests excluded)."""
    modules = {}
    for package_dir in sorted(src.glob(pattern)):
        if not (package_dir / '__init__.py').is_file():
            continue
        for path in sorted(package_dir.rglob('*.py')):
            parts = path.relative_to(package_dir.parent).with_suffix('').parts
            if parts[-1] == '__init__':
                parts = parts[:-1]
            modules['.'.join(parts)] = path
    return modules


def _resolve(name, modules):
    """The known module that `name` (a module or a name inside one) refers to, or None."""
    while name:
        if name in modules:
            return name
        name = name.rpartition('.')[0]
    return None


def import_graph(modules):
    """Module -> set of the known modules it imports (at any depth of its code)."""
    graph = {}
    for module, path in modules.items():
        is_package = path.name == '__init__.py'
        package = module if is_package else module.rpartition('.')[0]
        targets = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ''
                if node.level:
                    anchor = package.split('.')
                    anchor = anchor[: len(anchor) - (node.level - 1)]
                    base = '.'.join(anchor + ([base] if base else []))
                names = [f'{base}.{alias.name}' for alias in node.names] + [base]
            else:
                continue
            for name in names:
                target = _resolve(name, modules)
                if target is not None and target != module:
                    targets.add(target)
        graph[module] = targets
    return graph


def _package_of(module):
    return module.rpartition('.')[0] if '.' in module else module


def cycles(graph):
    """Strongly connected components of more than one module, each sorted, ignoring the edges
    from a package's __init__ to its own submodules (a package re-exporting its parts)."""
    edges = {
        module: {t for t in targets if not t.startswith(module + '.')}
        for module, targets in graph.items()
    }
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(module):  # Tarjan's algorithm; the graph is small, recursion is fine.
        index[module] = low[module] = len(index)
        stack.append(module)
        on_stack.add(module)
        for target in edges[module]:
            if target not in index:
                visit(target)
                low[module] = min(low[module], low[target])
            elif target in on_stack:
                low[module] = min(low[module], index[target])
        if low[module] == index[module]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == module:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for module in sorted(edges):
        if module not in index:
            visit(module)
    return sorted(found)


def layer_of(module):
    matches = [prefix for prefix in LAYERS if module == prefix or module.startswith(prefix + '.')]
    return LAYERS[max(matches, key=len)] if matches else None


def upward_imports(graph):
    """(importer, imported) pairs where the imported module sits in a higher layer."""
    return sorted(
        (module, target)
        for module, targets in graph.items()
        for target in targets
        if layer_of(target) is not None
        and layer_of(module) is not None
        and layer_of(target) > layer_of(module)
    )


@pytest.fixture(scope='module')
def graph():
    return import_graph({**module_files(), **module_files(BENCH, 'gsp_*')})


def test_the_graph_sees_every_package(graph):
    assert {module.split('.')[0] for module in graph} == {p.split('.')[0] for p in LAYERS}
    assert sum(len(targets) for targets in graph.values()) > 100


def test_no_import_cycles_under_src(graph):
    found = cycles(graph)
    assert not found, 'import cycles under src/: ' + '; '.join(' <-> '.join(c) for c in found)


def test_no_upward_imports(graph):
    found = upward_imports(graph)
    assert not found, 'imports into a higher layer: ' + '; '.join(
        f'{a} ({LAYER_NAMES[layer_of(a)]}) imports {b} ({LAYER_NAMES[layer_of(b)]})'
        for a, b in found
    )


def _tree(tmp_path, files):
    for relative, text in files.items():
        path = tmp_path / relative
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return import_graph(module_files(tmp_path))


def test_the_checks_catch_an_injected_cycle_and_an_upward_import(tmp_path):
    graph = _tree(
        tmp_path,
        {
            'gsp_kinematics/gsp_kinematics/__init__.py': '',
            'gsp_kinematics/gsp_kinematics/a.py': 'from gsp_kinematics.b import f\n',
            'gsp_kinematics/gsp_kinematics/b.py': 'def f():\n    from . import a\n',
            'gsp_msgs_py/gsp_msgs_py/__init__.py': '',
            'gsp_msgs_py/gsp_msgs_py/names.py': 'import gsp_kinematics.a\n',
            'gsp_calibrator/gsp_calibrator/__init__.py': '',
            'gsp_calibrator/gsp_calibrator/tools/__init__.py': '',
            'gsp_calibrator/gsp_calibrator/tools/demo.py': 'import gsp_msgs_py.names\n',
            'gsp_calibrator/gsp_calibrator/node.py': 'from .tools.demo import main\n',
            'gsp_calibrator/gsp_calibrator/report.py': 'from gsp_bench.verdict import run\n',
            'gsp_bench/gsp_bench/__init__.py': '',
            'gsp_bench/gsp_bench/verdict.py': 'import gsp_calibrator.tools.demo\n',
        },
    )
    assert cycles(graph) == [['gsp_kinematics.a', 'gsp_kinematics.b']]
    assert upward_imports(graph) == [
        ('gsp_calibrator.node', 'gsp_calibrator.tools.demo'),
        ('gsp_calibrator.report', 'gsp_bench.verdict'),
    ]
