"""The import graph of src/: no cycles between modules, and no import upwards across layers.

Layers, lowest first (docs/architecture.md): the core (gsp_kinematics, gsp_experiments), the
message layer (gsp_msgs_py), the nodes (gsp_platform_sim, gsp_platform_bridge,
gsp_device_driver, and gsp_calibrator's node side), the user tools (gsp_calibrator.tools). A
module may import its own layer or lower ones, never a higher one.
"""

import ast
from pathlib import Path

import pytest

WS = Path(__file__).resolve().parents[1]
SRC = WS / 'src'

#: Layer of each top-level package or subpackage; the longest matching prefix wins.
LAYERS = {
    'gsp_kinematics': 0,
    'gsp_experiments': 0,
    'gsp_msgs_py': 1,
    'gsp_platform_sim': 2,
    'gsp_platform_bridge': 2,
    'gsp_device_driver': 2,
    'gsp_calibrator': 2,
    'gsp_calibrator.tools': 3,
}
LAYER_NAMES = ('core', 'message layer', 'nodes', 'tools')


def module_files(src=SRC):
    """Module name -> source file of every package module under `src` (tests excluded)."""
    modules = {}
    for package_dir in sorted(src.glob('*/gsp_*')):
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
    return import_graph(module_files())


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
        },
    )
    assert cycles(graph) == [['gsp_kinematics.a', 'gsp_kinematics.b']]
    assert upward_imports(graph) == [('gsp_calibrator.node', 'gsp_calibrator.tools.demo')]


#: Floors inside gsp_calibrator, lowest first; a module imports its own floor or lower ones.
#: The upkeep parameters are part of the one parameter table that ``settings`` reads.
CALIBRATOR_FLOORS = {
    'gsp_calibrator.settings': 0,
    'gsp_calibrator.launch_arguments': 0,
    'gsp_calibrator.upkeep.parameters': 0,
    'gsp_calibrator.collection': 1,
    'gsp_calibrator.recording': 1,
    'gsp_calibrator.report': 1,
    'gsp_calibrator.files': 1,
    'gsp_calibrator.run': 2,
    'gsp_calibrator.upkeep': 3,
    'gsp_calibrator.replay': 3,
    'gsp_calibrator.node': 4,
    'gsp_calibrator.tools': 5,
}
CALIBRATOR_FLOOR_NAMES = ('settings', 'leaves', 'run', 'upkeep, replay', 'node', 'tools')


def calibrator_floor(module):
    """The floor of a gsp_calibrator module (longest prefix wins), None outside the table."""
    matches = [p for p in CALIBRATOR_FLOORS if module == p or module.startswith(p + '.')]
    return CALIBRATOR_FLOORS[max(matches, key=len)] if matches else None


def calibrator_back_arrows(graph):
    """(importer, imported) pairs inside gsp_calibrator where the imported sits on a higher floor."""
    return sorted(
        (module, target)
        for module, targets in graph.items()
        for target in targets
        if calibrator_floor(module) is not None
        and calibrator_floor(target) is not None
        and calibrator_floor(target) > calibrator_floor(module)
    )


def test_every_calibrator_module_has_a_floor(graph):
    unplaced = [m for m in graph if m.startswith('gsp_calibrator.') and calibrator_floor(m) is None]
    assert not unplaced, f'gsp_calibrator modules without a floor: {unplaced}'


def test_no_arrow_back_up_in_the_calibrator(graph):
    found = calibrator_back_arrows(graph)
    assert not found, 'gsp_calibrator imports into a higher floor: ' + '; '.join(
        f'{a} ({CALIBRATOR_FLOOR_NAMES[calibrator_floor(a)]}) imports {b} '
        f'({CALIBRATOR_FLOOR_NAMES[calibrator_floor(b)]})'
        for a, b in found
    )


def test_the_floors_catch_a_run_that_imports_upkeep(tmp_path):
    graph = _tree(
        tmp_path,
        {
            'gsp_calibrator/gsp_calibrator/__init__.py': '',
            'gsp_calibrator/gsp_calibrator/run/__init__.py': '',
            'gsp_calibrator/gsp_calibrator/run/flow.py': 'from ..upkeep.check_flow import f\n',
            'gsp_calibrator/gsp_calibrator/upkeep/__init__.py': '',
            'gsp_calibrator/gsp_calibrator/upkeep/check_flow.py': 'import gsp_calibrator.run\n',
            'gsp_calibrator/gsp_calibrator/files/__init__.py': '',
            'gsp_calibrator/gsp_calibrator/files/history.py': 'import gsp_calibrator.run.flow\n',
        },
    )
    assert calibrator_back_arrows(graph) == [
        ('gsp_calibrator.files.history', 'gsp_calibrator.run.flow'),
        ('gsp_calibrator.run.flow', 'gsp_calibrator.upkeep.check_flow'),
    ]
