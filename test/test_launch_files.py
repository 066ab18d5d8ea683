"""The launch files: installed, valid Python on the stable launch/launch_ros API, consistent.

``launch`` is not on PyPI, so their structure is checked from the source (AST); where
``launch_ros`` is importable the descriptions are also built.
"""

import ast
import configparser
import importlib.util
import sys
import types
from pathlib import Path

import pytest

WS = Path(__file__).resolve().parents[1]
LAUNCH_DIR = WS / 'src' / 'gsp_calibrator' / 'launch'
LAUNCH_FILES = sorted(LAUNCH_DIR.glob('*.launch.py'))
#: The package's launch helper (installed with it), imported by the launch files.
HELPER_PACKAGE = 'gsp_calibrator'
HELPER_MODULE = f'{HELPER_PACKAGE}.launch_arguments'
HELPER_FILE = WS / 'src' / 'gsp_calibrator' / 'gsp_calibrator' / 'launch_arguments.py'
#: The stable API the files may use.
ALLOWED_IMPORTS = {
    'launch': {'LaunchDescription'},
    'launch.actions': {'DeclareLaunchArgument'},
    'launch.substitutions': {'LaunchConfiguration', 'PathJoinSubstitution'},
    'launch_ros.actions': {'Node'},
    'launch_ros.parameter_descriptions': {'ParameterValue'},
    'launch_ros.substitutions': {'FindPackageShare'},
}


def console_scripts(package):
    config = configparser.ConfigParser()
    config.read(WS / 'src' / package / 'setup.cfg')
    entries = config.get('options.entry_points', 'console_scripts', fallback='')
    return {line.split('=')[0].strip() for line in entries.splitlines() if line.strip()}


def test_the_three_launch_files_are_installed_by_setup_cfg():
    assert [p.name for p in LAUNCH_FILES] == [
        'calibrator.launch.py',
        'hardware.launch.py',
        'sim_suite.launch.py',
    ]
    config = configparser.ConfigParser()
    config.read(WS / 'src' / 'gsp_calibrator' / 'setup.cfg')
    assert 'launch/*.launch.py' in config.get('options.data_files', 'share/gsp_calibrator/launch')


def imports(tree):
    """``{module: {names}}`` of the from-imports of ``tree``; AssertionError on a plain import."""
    found = {}
    for node in ast.walk(tree):
        assert not isinstance(node, ast.Import), 'only from-imports of the stable API'
        if isinstance(node, ast.ImportFrom):
            found.setdefault(node.module, set()).update(a.name for a in node.names)
    return found


def test_the_shared_helper_is_installed_with_the_package_and_uses_the_stable_api():
    # packages = find: installs every module of the gsp_calibrator package.
    assert HELPER_FILE.is_file()
    assert 'find:' in configparser_value('options', 'packages')
    for module, names in imports(ast.parse(HELPER_FILE.read_text())).items():
        assert module in ALLOWED_IMPORTS, module
        assert names <= ALLOWED_IMPORTS[module], names - ALLOWED_IMPORTS[module]


def configparser_value(section, option):
    config = configparser.ConfigParser()
    config.read(WS / 'src' / 'gsp_calibrator' / 'setup.cfg')
    return config.get(section, option)


class _Recorded:
    """A stand-in launch action or substitution: it keeps its arguments."""

    def __init__(self, *args, **kwargs):
        self.args, self.kwargs = args, kwargs


@pytest.fixture
def stable_api_stubs(monkeypatch):
    """Stand-in ``launch``/``launch_ros`` modules holding only the stable API (an import of
    anything else fails); the helper is imported afresh against them."""
    for module, names in ALLOWED_IMPORTS.items():
        stub = types.ModuleType(module)
        for name in names:
            setattr(stub, name, type(name, (_Recorded,), {}))
        monkeypatch.setitem(sys.modules, module, stub)
    monkeypatch.setitem(sys.modules, 'launch_ros', types.ModuleType('launch_ros'))
    monkeypatch.delitem(sys.modules, HELPER_MODULE, raising=False)
    yield
    sys.modules.pop(HELPER_MODULE, None)


def recorded(value, kind):
    """Every stand-in of class ``kind`` inside ``value`` (lists, dicts, their arguments)."""
    if isinstance(value, _Recorded):
        found = [value] if type(value).__name__ == kind else []
        for item in (*value.args, *value.kwargs.values()):
            found += recorded(item, kind)
        return found
    if isinstance(value, dict):
        value = list(value.values())
    if isinstance(value, (list, tuple)):
        return [found for item in value for found in recorded(item, kind)]
    return []


@pytest.mark.parametrize('path', LAUNCH_FILES, ids=lambda p: p.name)
def test_a_launch_file_uses_the_stable_api_and_names_real_executables(path, stable_api_stubs):
    source = path.read_text()
    compile(source, str(path), 'exec')
    tree = ast.parse(source)
    for module, names in imports(tree).items():
        if module == HELPER_PACKAGE:
            assert names == {'launch_arguments'}, names
            continue
        assert module in ALLOWED_IMPORTS, module
        assert names <= ALLOWED_IMPORTS[module], names
    functions = [n.name for n in tree.body if isinstance(n, ast.FunctionDef)]
    assert functions == ['generate_launch_description']

    # Built against the stand-ins: what the file declares, uses and starts.
    spec = importlib.util.spec_from_file_location(path.stem.replace('.', '_'), path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    description = module.generate_launch_description()
    (entities,) = description.args
    arguments = {e.args[0] for e in entities if type(e).__name__ == 'DeclareLaunchArgument'}
    assert {'params_file', 'use_sim_time'} <= arguments
    used = {c.args[0] for c in recorded(entities, 'LaunchConfiguration')}
    assert used <= arguments, used - arguments
    nodes = [e for e in entities if type(e).__name__ == 'Node']
    assert nodes
    for node in nodes:
        keywords = node.kwargs
        assert keywords['executable'] in console_scripts(keywords['package']), keywords
        assert keywords['name'] == keywords['executable']
        parameters = keywords['parameters']
        # The use_sim_time argument reaches every node, as a bool.
        (sim_time,) = [
            p['use_sim_time'] for p in parameters if isinstance(p, dict) and 'use_sim_time' in p
        ]
        assert sim_time.kwargs == {'value_type': bool}
        assert sim_time.args[0].args == ('use_sim_time',)
    for share in recorded(entities, 'FindPackageShare'):
        assert (WS / 'src' / share.args[0] / 'package.xml').exists()


#: Why the real build is skipped here; the test above still builds every file against stand-ins.
WITHOUT_LAUNCH_ROS = (
    'NOT RUN: launch_ros is not installable from PyPI, so the descriptions are not built with the '
    'real launch/launch_ros here, only against stand-ins of their stable API '
    '(test_a_launch_file_uses_the_stable_api_and_names_real_executables); this test runs in a '
    'ROS install'
)


@pytest.mark.skipif(importlib.util.find_spec('launch_ros') is None, reason=WITHOUT_LAUNCH_ROS)
@pytest.mark.parametrize('path', LAUNCH_FILES, ids=lambda p: p.name)
def test_a_launch_description_builds_with_the_real_launch_ros_only_in_a_ros_install(path):
    spec = importlib.util.spec_from_file_location(path.stem.replace('.', '_'), path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert module.generate_launch_description().entities
