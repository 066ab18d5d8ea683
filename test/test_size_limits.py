"""Size limits of the package sources under src/ and of the bench (bench/gsp_bench), tests
excluded: a file a newcomer can read.

No file over MAX_FILE_LINES lines, no class over MAX_CLASS_LINES, no function or method over
MAX_FUNCTION_LINES, unless it is listed in EXCEPTIONS with the reason: a flat table (an argument
parser, a parameter list), or one concept a split would cut in two. Lines are source lines,
docstrings and comments included.
"""

import ast
from pathlib import Path

import pytest

WS = Path(__file__).resolve().parents[1]
SRC = WS / 'src'

MAX_FILE_LINES = 500
MAX_CLASS_LINES = 300
MAX_FUNCTION_LINES = 80

#: ``'package/path.py'`` (a file) or ``'package/path.py:qualified.name'`` (a class or a function)
#: -> why it may exceed its limit. An entry no longer needed fails the test: none is kept "just in
#: case".
EXCEPTIONS = {
    'gsp_calibrator/settings.py': "a flat table: the calibrator's parameters (one ParameterSpec "
    'each, with its subsets) and the settings, command-line options and checks derived from it',
}


def source_files(src=SRC, pattern='*/gsp_*'):
    """``{'package/path.py': Path}`` of every package module under ``src`` (tests excluded)."""
    files = {}
    for package_dir in sorted(src.glob(pattern)):
        if (package_dir / '__init__.py').is_file():
            for path in sorted(package_dir.rglob('*.py')):
                files[path.relative_to(package_dir.parent).as_posix()] = path
    return files


def _definitions(tree):
    """``(kind, qualified name, lines)`` of every class and function of ``tree``, nested too."""
    found = []

    def visit(node, prefix):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
                name = f'{prefix}{child.name}'
                kind = 'class' if isinstance(child, ast.ClassDef) else 'function'
                found.append((kind, name, child.end_lineno - child.lineno + 1))
                visit(child, f'{name}.')
            else:
                visit(child, prefix)

    visit(tree, '')
    return found


def oversized(files, exceptions=EXCEPTIONS):
    """Human-readable violations of the limits in ``files`` (``source_files()``)."""
    found = []
    for relative, path in files.items():
        text = path.read_text()
        lines = len(text.splitlines())
        if lines > MAX_FILE_LINES and relative not in exceptions:
            found.append(f'{relative}: {lines} lines (> {MAX_FILE_LINES})')
        for kind, name, length in _definitions(ast.parse(text, str(path))):
            limit = MAX_CLASS_LINES if kind == 'class' else MAX_FUNCTION_LINES
            if length > limit and f'{relative}:{name}' not in exceptions:
                found.append(f'{relative}: {kind} {name} is {length} lines (> {limit})')
    return found


@pytest.fixture(scope='module')
def files():
    return {**source_files(), **source_files(WS / 'bench', 'gsp_*')}


def test_the_check_sees_every_package(files):
    packages = {relative.split('/')[0] for relative in files}
    assert {
        'gsp_kinematics',
        'gsp_msgs_py',
        'gsp_calibrator',
        'gsp_device_driver',
        'gsp_bench',
    } <= packages
    assert len(files) > 50


def test_no_file_class_or_function_over_its_limit(files):
    found = oversized(files)
    assert not found, 'over the size limits (split by concept):\n' + '\n'.join(found)


def sizes(files):
    """``{'package/path.py': lines, 'package/path.py:name': lines}`` of every file, class and
    function, with the limit each is held to."""
    found = {}
    for relative, path in files.items():
        text = path.read_text()
        found[relative] = (len(text.splitlines()), MAX_FILE_LINES)
        for kind, name, length in _definitions(ast.parse(text)):
            limit = MAX_CLASS_LINES if kind == 'class' else MAX_FUNCTION_LINES
            found[f'{relative}:{name}'] = (length, limit)
    return found


def test_every_exception_states_its_reason_and_is_still_needed(files):
    known = sizes(files)
    stale = [key for key in EXCEPTIONS if known.get(key, (0, 1))[0] <= known.get(key, (0, 1))[1]]
    assert not stale, f'EXCEPTIONS entries no longer needed: {stale}'
    assert all(reason.strip() for reason in EXCEPTIONS.values())


def test_the_check_catches_a_long_file_class_and_function(tmp_path):
    package = tmp_path / 'gsp_x' / 'gsp_x'
    package.mkdir(parents=True)
    (package / '__init__.py').write_text('')
    body = ''.join(f'    x{i} = {i}\n' for i in range(MAX_FUNCTION_LINES))  # def + body: 81
    methods = ''.join(
        f'    def m{k}(self):\n' + body.replace('    x', '        x') for k in range(7)
    )
    (package / 'big.py').write_text(f'def long():\n{body}\n\nclass Big:\n{methods}')
    (package / 'table.py').write_text(f'def parser():\n{body}')
    found = oversized(source_files(tmp_path), exceptions={'gsp_x/table.py:parser': 'a table'})
    assert found == [
        f'gsp_x/big.py: {81 + 2 + 1 + 7 * 81} lines (> {MAX_FILE_LINES})',
        f'gsp_x/big.py: function long is 81 lines (> {MAX_FUNCTION_LINES})',
        f'gsp_x/big.py: class Big is {1 + 7 * 81} lines (> {MAX_CLASS_LINES})',
        *(
            f'gsp_x/big.py: function Big.m{k} is 81 lines (> {MAX_FUNCTION_LINES})'
            for k in range(7)
        ),
    ]
