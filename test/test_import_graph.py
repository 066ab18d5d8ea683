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

#: Floors inside the core (docs/architecture.md), lowest first: the leaves at the package's top
#: (channels, rotation, fileio), the physics, the estimation, the planning, the upkeep. A core
#: module may import its own floor or lower ones, never a higher one.
CORE_FLOORS = {
    'gsp_kinematics': 0,
    'gsp_kinematics.model': 1,
    'gsp_kinematics.estimation': 2,
    'gsp_kinematics.planning': 3,
    'gsp_kinematics.upkeep': 4,
}
CORE_FLOOR_NAMES = ('leaves', 'model', 'estimation', 'planning', 'upkeep')


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


def layer_of(module, layers=LAYERS):
    matches = [prefix for prefix in layers if module == prefix or module.startswith(prefix + '.')]
    return layers[max(matches, key=len)] if matches else None


def upward_imports(graph, layers=LAYERS):
    """(importer, imported) pairs where the imported module sits in a higher layer."""
    return sorted(
        (module, target)
        for module, targets in graph.items()
        for target in targets
        if layer_of(target, layers) is not None
        and layer_of(module, layers) is not None
        and layer_of(target, layers) > layer_of(module, layers)
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


def test_the_core_has_no_import_back_up_its_floors(graph):
    found = upward_imports(graph, CORE_FLOORS)
    assert not found, 'core imports into a higher floor: ' + '; '.join(
        f'{a} ({CORE_FLOOR_NAMES[layer_of(a, CORE_FLOORS)]}) imports {b} '
        f'({CORE_FLOOR_NAMES[layer_of(b, CORE_FLOORS)]})'
        for a, b in found
    )


def test_every_core_subpackage_has_its_floor(graph):
    """A new folder in the core is given a floor here; the top holds only the leaves."""
    core = [m for m in graph if m.startswith('gsp_kinematics.')]
    folders = {'.'.join(m.split('.')[:2]) for m in core if m.count('.') >= 2}
    assert folders <= set(CORE_FLOORS), sorted(folders - set(CORE_FLOORS))
    top = {m for m in core if m.count('.') == 1 and m not in CORE_FLOORS}
    assert top == {'gsp_kinematics.channels', 'gsp_kinematics.rotation', 'gsp_kinematics.fileio'}
    assert not any(graph[m] for m in top), 'the leaves import nothing of the core'


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


def test_the_floor_check_catches_a_core_import_back_up(tmp_path):
    graph = _tree(
        tmp_path,
        {
            'gsp_kinematics/gsp_kinematics/__init__.py': '',
            'gsp_kinematics/gsp_kinematics/model/__init__.py': '',
            'gsp_kinematics/gsp_kinematics/model/geometry.py': (
                'from gsp_kinematics.planning.selection import f\n'
            ),
            'gsp_kinematics/gsp_kinematics/planning/__init__.py': '',
            'gsp_kinematics/gsp_kinematics/planning/selection.py': (
                'from ..model import geometry\ndef f():\n    pass\n'
            ),
        },
    )
    assert upward_imports(graph, CORE_FLOORS) == [
        ('gsp_kinematics.model.geometry', 'gsp_kinematics.planning.selection')
    ]


#: Floors inside gsp_calibrator, lowest first; a module imports its own floor or lower ones.
#: `settings_fields` holds the typed fields of the one parameter table that `settings` reads.
CALIBRATOR_FLOORS = {
    'gsp_calibrator.settings': 0,
    'gsp_calibrator.launch_arguments': 0,
    'gsp_calibrator.settings_fields': 0,
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
