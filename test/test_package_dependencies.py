"""Each package.xml lists every runtime dependency its package's code imports.

A module imported anywhere in a package's shipped code (tests excluded, imports inside functions
included) must be the package itself, the standard library, or an ``exec_depend``/``depend`` of
its package.xml, named by its rosdep key (:data:`ROSDEP_KEYS`; a ROS package by its own name).
"""

import ast
import sys
import xml.etree.ElementTree as ElementTree
from pathlib import Path

import pytest

WS = Path(__file__).resolve().parents[1]
SRC = WS / 'src'
PACKAGES = sorted(path.parent.name for path in SRC.glob('*/package.xml'))

#: Python module -> the rosdep key of the library that provides it.
ROSDEP_KEYS = {
    'numpy': 'python3-numpy',
    'scipy': 'python3-scipy',
    'yaml': 'python3-yaml',
    'matplotlib': 'python3-matplotlib',
    'serial': 'python3-serial',
    'mcap': 'python3-mcap',
    'mcap_ros2': 'python3-mcap-ros2-support',
    'mujoco': 'python3-mujoco-pip',
}


def imported_modules(package):
    """Top-level names of the modules ``package``'s shipped code imports (absolute imports)."""
    found = set()
    for path in (SRC / package / package).rglob('*.py'):
        for node in ast.walk(ast.parse(path.read_text(encoding='utf-8'))):
            if isinstance(node, ast.Import):
                found.update(alias.name.split('.')[0] for alias in node.names)
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                found.add(node.module.split('.')[0])
    return found - set(sys.stdlib_module_names) - {package}


def runtime_dependencies(package):
    """The ``exec_depend`` and ``depend`` entries of ``package``'s package.xml."""
    root = ElementTree.parse(SRC / package / 'package.xml').getroot()
    return {element.text.strip() for tag in ('exec_depend', 'depend') for element in root.iter(tag)}


def missing_dependencies(package):
    """The rosdep keys ``package`` imports but its package.xml does not list."""
    wanted = {ROSDEP_KEYS.get(module, module) for module in imported_modules(package)}
    return sorted(wanted - runtime_dependencies(package))


@pytest.mark.parametrize('package', PACKAGES)
def test_package_xml_lists_every_runtime_import(package):
    missing = missing_dependencies(package)
    assert not missing, f'src/{package}/package.xml lacks <exec_depend> for {missing}'


def test_the_check_sees_the_calibrators_plots_and_recordings():
    assert {'matplotlib', 'mcap', 'rclpy', 'gsp_kinematics'} <= imported_modules('gsp_calibrator')


def modules_importing_tests(directory):
    """``{test module: [test_* modules it imports]}`` in ``directory`` (tests' own imports)."""
    found = {}
    for path in sorted(directory.rglob('*.py')):
        for node in ast.walk(ast.parse(path.read_text(encoding='utf-8'))):
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            else:
                continue
            tests = [name for name in names if name.split('.')[0].startswith('test_')]
            if tests:
                found.setdefault(str(path.relative_to(WS)), []).extend(tests)
    return found


@pytest.mark.parametrize('directory', [*(f'src/{p}/test' for p in PACKAGES), 'test'])
def test_no_test_module_imports_another(directory):
    """What tests share lives in test_support/, so that each test module stands alone (pytest
    collects an imported test module's tests twice, and its fixtures leak into the importer)."""
    importing = modules_importing_tests(WS / directory)
    assert not importing, (
        f'test modules import other test modules (move it to test_support/): {importing}'
    )
