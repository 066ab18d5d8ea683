"""The launch files: installed, valid Python on the stable launch/launch_ros API, consistent.

``launch`` is not on PyPI, so their structure is checked from the source (AST); where
``launch_ros`` is importable the descriptions are also built.
"""

import ast
import configparser
import importlib.util
from pathlib import Path

import pytest

WS = Path(__file__).resolve().parents[1]
LAUNCH_DIR = WS / 'src' / 'gsp_calibrator' / 'launch'
LAUNCH_FILES = sorted(LAUNCH_DIR.glob('*.launch.py'))
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


def keyword_strings(call):
    return {
        k.arg: k.value.value
        for k in call.keywords
        if isinstance(k.value, ast.Constant) and isinstance(k.value.value, str)
    }


def calls(tree, name):
    return [
        node
        for node in ast.walk(tree)
        if isinstance(node, ast.Call) and getattr(node.func, 'id', None) == name
    ]


def test_the_three_launch_files_are_installed_by_setup_cfg():
    assert [p.name for p in LAUNCH_FILES] == [
        'calibrator.launch.py',
        'hardware.launch.py',
        'sim_suite.launch.py',
    ]
    config = configparser.ConfigParser()
    config.read(WS / 'src' / 'gsp_calibrator' / 'setup.cfg')
    assert 'launch/*.launch.py' in config.get('options.data_files', 'share/gsp_calibrator/launch')


@pytest.mark.parametrize('path', LAUNCH_FILES, ids=lambda p: p.name)
def test_a_launch_file_uses_the_stable_api_and_names_real_executables(path):
    source = path.read_text()
    compile(source, str(path), 'exec')
    tree = ast.parse(source)
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            assert node.module in ALLOWED_IMPORTS, node.module
            assert {a.name for a in node.names} <= ALLOWED_IMPORTS[node.module]
        assert not isinstance(node, ast.Import), 'only from-imports of the stable API'
    functions = [n.name for n in tree.body if isinstance(n, ast.FunctionDef)]
    assert functions == ['generate_launch_description']
    arguments = {
        keyword_strings(c).get('name') or c.args[0].value
        for c in calls(tree, 'DeclareLaunchArgument')
    }
    assert {'params_file', 'use_sim_time'} <= arguments
    used = {c.args[0].value for c in calls(tree, 'LaunchConfiguration')}
    assert used <= arguments, used - arguments
    nodes = calls(tree, 'Node')
    assert nodes
    for node in nodes:
        keywords = keyword_strings(node)
        assert keywords['executable'] in console_scripts(keywords['package']), keywords
        assert 'parameters' in {k.arg for k in node.keywords}
    for share in calls(tree, 'FindPackageShare'):
        assert (WS / 'src' / share.args[0].value / 'package.xml').exists()


@pytest.mark.skipif(importlib.util.find_spec('launch_ros') is None, reason='launch_ros absent')
@pytest.mark.parametrize('path', LAUNCH_FILES, ids=lambda p: p.name)
def test_a_launch_description_builds_where_launch_ros_is_installed(path):
    spec = importlib.util.spec_from_file_location(path.stem.replace('.', '_'), path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert module.generate_launch_description().entities
