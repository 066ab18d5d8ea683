"""The docs match the code: docs/parameters.md and docs/figures.md are generated (from the nodes'
spec tables, from the committed bench and paper JSON), every relative link of the README and
docs/ reaches a file and a heading, and every source path and module name they give exists."""

import ast
import builtins
import importlib.machinery
import importlib.util
import re
from pathlib import Path

import pytest

WS = Path(__file__).resolve().parents[1]


def _generator(name='gen-parameter-docs'):
    path = WS / 'scripts' / name
    loader = importlib.machinery.SourceFileLoader(name.replace('-', '_'), str(path))
    module = importlib.util.module_from_spec(importlib.util.spec_from_loader(loader.name, loader))
    loader.exec_module(module)
    return module


def test_parameter_docs_match_the_spec_tables():
    generator = _generator()
    assert generator.OUTPUT.read_text() == generator.render(), (
        f'docs/parameters.md is out of date: run `{generator.COMMAND}` and commit the result'
    )


def test_parameter_table_rows_escape_the_markdown():
    from gsp_msgs_py.parameter_specs import ParameterSpec

    specs = [
        ParameterSpec('rate', 200.0, 'Rate', unit='Hz', read_only=True, constraints='> 0'),
        ParameterSpec('noise', 1e-6, 'Noise std', unit='m', float_range=(0.0, 1.0)),
        ParameterSpec('names', ['x', 'y'], 'Names | with a pipe, <tag>'),
    ]
    lines = _generator().parameter_table_markdown(specs).splitlines()
    assert lines[0] == '| name | type | default | unit | read-only | constraints | description |'
    assert lines[2] == '| `rate` | double | `200` | Hz | yes | > 0 | Rate |'
    assert lines[3] == '| `noise` | double | `1e-06` | m | no | in [0, 1] | Noise std |'
    assert lines[4] == (
        "| `names` | string_array | `['x', 'y']` |  | no |  | Names \\| with a pipe, &lt;tag> |"
    )


#: docs/ is reference, not history: at most this many lines (issue 35), the generated pages too.
DOCS_LINE_BUDGET = 3000


def test_the_docs_stay_within_their_line_budget():
    lines = sum(len(path.read_text(encoding='utf-8').splitlines()) for path in DOCS[1:])
    assert lines <= DOCS_LINE_BUDGET, (
        f'docs/*.md hold {lines} lines, over {DOCS_LINE_BUDGET}: say what the code does today, '
        'once; history goes to CHANGELOG.md'
    )


def test_figures_match_the_committed_json():
    generator = _generator('gen-figures')
    assert generator.OUTPUT.read_text() == generator.render(), (
        f'docs/figures.md is out of date: run `{generator.COMMAND}` and commit the result'
    )


def test_the_figures_page_renders_every_number_of_the_json():
    generator = _generator('gen-figures')
    document = {'section': {'description': 'what', 'a': {'b': 0.000123456, 'c': [1, 2]}}}
    text = generator.render_document('bench', document)
    assert '| **section** `a` | `b` 0.0001235; `c` [1, 2] |' in text
    assert '| **section** description | what |' in text


# --- names in the docs ---------------------------------------------------------------------------

DOCS = [WS / 'README.md', *sorted((WS / 'docs').glob('*.md'))]
SRC = WS / 'src'
#: Every Python file of the project (this file's own examples aside).
PYTHON_FILES_FOR_REFERENCES = sorted(
    path
    for folder in ('src', 'test', 'test_support', 'bench')
    for path in (WS / folder).glob('**/*.py')
    if path != Path(__file__).resolve()
)
#: The benchmark and the paper reproduction (bench/gsp_bench: not a package under src/).
BENCH = WS / 'bench'
PACKAGES = sorted(
    path.name
    for path in [*SRC.glob('*/gsp_*'), *BENCH.glob('gsp_*')]
    if (path / '__init__.py').is_file()
)


def _expand(path):
    """``a/{b,c}`` -> ``a/b``, ``a/c`` (one brace group)."""
    head, brace, rest = path.partition('{')
    if not brace:
        return [path]
    choices, _, tail = rest.partition('}')
    return [f'{head}{choice}{tail}' for choice in choices.split(',')]


def _module_path(parts):
    """The source file (or package folder) of module ``parts`` under src/ or bench/, or None."""
    base = BENCH / parts[0] if parts[0] == 'gsp_bench' else SRC / parts[0] / parts[0]
    path = base.joinpath(*parts[1:])
    if path.with_suffix('.py').is_file():
        return path.with_suffix('.py')
    if (path / '__init__.py').is_file():
        return path / '__init__.py'
    return None


def _defines(source, name):
    """Whether the module file ``source`` defines or imports ``name`` at its top level."""
    tree = ast.parse(source.read_text())
    for node in tree.body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            found = node.name == name
        elif isinstance(node, ast.Assign):
            found = any(getattr(t, 'id', None) == name for t in node.targets)
        elif isinstance(node, ast.AnnAssign):
            found = getattr(node.target, 'id', None) == name
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            found = any((a.asname or a.name.split('.')[0]) == name for a in node.names)
        else:
            found = False
        if found:
            return True
    return False


def dangling_names(text):
    """Source paths and dotted module names in ``text`` that do not exist in src/ or bench/."""
    missing = []
    for path in re.findall(r'`((?:src|bench)/[^`\s]+)`', text):
        missing += [p for p in _expand(path) if not (WS / p.rstrip('/')).exists()]
    for dotted in re.findall(r'\b(gsp_[a-z_]+(?:\.[A-Za-z_]\w*)+)', text):
        parts = dotted.split('.')
        if parts[0] not in PACKAGES:
            continue
        for length in range(len(parts), 0, -1):
            source = _module_path(parts[:length])
            if source is not None:
                break
        rest = parts[length:]
        if rest and not _defines(source, rest[0]):
            missing.append(dotted)
    return sorted(set(missing))


@pytest.mark.parametrize('doc', DOCS, ids=lambda path: path.name)
def test_the_docs_name_only_modules_and_files_that_exist(doc):
    text = doc.read_text(encoding='utf-8')
    missing = dangling_names(text) + [
        name
        for pair in _FILE.findall(text)
        for name in _expand(pair[0] or pair[1])
        if Path(name).name not in _FILE_NAMES
    ]
    assert not missing, f'{doc.name} names what src/ does not hold: {missing}'


# --- the README's map -----------------------------------------------------------------------------

#: Every package's direct subpackages (``gsp_calibrator/upkeep``...) and the console scripts
#: (the benchmarks' entry points are documented as ``make bench`` and ``make paper``).
SUBPACKAGES = sorted(
    path.parent.relative_to(SRC / path.parts[-4]).as_posix()
    for path in SRC.glob('*/gsp_*/*/__init__.py')
)
CONSOLE_SCRIPTS = sorted(
    name.strip()
    for setup in SRC.glob('*/setup.cfg')
    for name, _, target in (line.partition('=') for line in setup.read_text().splitlines())
    if ':main' in target and 'bench' not in target and 'gsp_experiments' not in target
)


def test_the_readme_names_every_subpackage_and_tool():
    text = (WS / 'README.md').read_text(encoding='utf-8')
    missing = [name for name in SUBPACKAGES if f'`{name.split("/")[1]}/`' not in text]
    missing += [name for name in CONSOLE_SCRIPTS if f'`{name}`' not in text]
    assert not missing, f'README.md does not name: {missing}'


# --- a package's list of its modules --------------------------------------------------------------

#: ```name`` (what it is)` or `(``name``)` in a package's docstring: one of its modules.
_LISTED_MODULE = re.compile(r'``(\w+)`` \(|\(``(\w+)``')
PACKAGE_INITS = sorted(SRC.glob('*/gsp_*/**/__init__.py'))


def unknown_listed_modules(init):
    """The modules a package's docstring lists (see ``_LISTED_MODULE``) that it does not hold."""
    folder = init.parent
    tree = ast.parse(init.read_text(encoding='utf-8'))
    listed = [a or b for a, b in _LISTED_MODULE.findall(ast.get_docstring(tree) or '')]
    return [
        name
        for name in listed
        if not name.startswith('gsp_')  # a console script or a package
        and not (folder / f'{name}.py').is_file()
        and not (folder / name / '__init__.py').is_file()
        and name not in _top_level_names(tree)
    ]


@pytest.mark.parametrize('init', PACKAGE_INITS, ids=lambda path: str(path.relative_to(SRC)))
def test_a_package_lists_only_modules_it_holds(init):
    unknown = unknown_listed_modules(init)
    assert not unknown, f'{init.relative_to(WS)} lists modules it does not hold: {unknown}'


def test_the_module_list_check_sees_a_missing_module(tmp_path):
    (tmp_path / 'names.py').write_text('')
    init = tmp_path / '__init__.py'
    init.write_text('"""``names`` (topics), ``checks`` (poses), the rule (``names``)."""\n')
    assert unknown_listed_modules(init) == ['checks']


# --- links in the docs ---------------------------------------------------------------------------

_LINK = re.compile(r'\[[^\]]*\]\(([^)\s]+)\)')
_FENCE = re.compile(r'^```.*?^```', re.M | re.S)


def anchors(text):
    """The #anchors GitHub gives the headings of Markdown ``text`` (duplicates get -1, -2...)."""
    seen = {}
    for heading in re.findall(r'^#{1,6} +(.+?) *$', _FENCE.sub('', text), re.M):
        slug = re.sub(r'[^\w\- ]', '', heading.lower()).replace(' ', '-')
        count = seen.get(slug, 0)
        seen[slug] = count + 1
        yield slug if count == 0 else f'{slug}-{count}'


def broken_links(doc, text):
    """The relative links of ``text`` (a file at ``doc``) whose file or #anchor does not exist."""
    broken = []
    for target in _LINK.findall(_FENCE.sub('', text)):
        if re.match(r'[a-z]+:', target):
            continue  # http:, https:, mailto:
        path, _, anchor = target.partition('#')
        file = (doc.parent / path).resolve() if path else doc
        if not file.exists():
            broken.append(target)
        elif anchor and file.suffix == '.md' and anchor not in set(anchors(file.read_text())):
            broken.append(target)
    return broken


@pytest.mark.parametrize('doc', DOCS, ids=lambda path: path.name)
def test_every_link_reaches_a_file_and_a_heading(doc):
    broken = broken_links(doc, doc.read_text(encoding='utf-8'))
    assert not broken, f'{doc.name} links to what does not exist: {broken}'


#: ``docs/<page>.md`` or ``docs/<page>.md#<anchor>`` named in code, tests, scripts or the Makefile.
_DOCS_REFERENCE = re.compile(r'docs/([a-z_]+\.md)(?:#([a-z0-9_-]+))?')
CODE_FILES = [
    *PYTHON_FILES_FOR_REFERENCES,
    *(path for path in (WS / 'scripts').iterdir() if path.is_file()),
    WS / 'Makefile',
]


def dangling_docs_references(text):
    """The ``docs/...md#anchor`` references of ``text`` whose page or heading does not exist."""
    missing = []
    for page, anchor in _DOCS_REFERENCE.findall(text):
        path = WS / 'docs' / page
        if not path.is_file() or (anchor and anchor not in set(anchors(path.read_text()))):
            missing.append(f'docs/{page}' + (f'#{anchor}' if anchor else ''))
    return missing


def test_code_names_only_docs_pages_and_headings_that_exist():
    missing = {
        str(path.relative_to(WS)): found
        for path in CODE_FILES
        if (found := dangling_docs_references(path.read_text(encoding='utf-8', errors='ignore')))
    }
    assert not missing, f'docs pages or headings named in code do not exist: {missing}'


def test_the_link_check_sees_a_missing_file_and_a_missing_heading():
    doc = WS / 'docs' / 'nodes.md'
    assert broken_links(doc, '[a](nodes.md) [b](#interfaces) [c](https://x.org/y)') == []
    assert broken_links(doc, '[a](gone.md) [b](nodes.md#no-such-heading)') == [
        'gone.md',
        'nodes.md#no-such-heading',
    ]
    assert dangling_docs_references('docs/nodes.md#diagnostics, docs/gone.md, docs/nodes.md#x') == [
        'docs/gone.md',
        'docs/nodes.md#x',
    ]
    assert list(anchors('## The `run` (a), b.json\n## The `run` (a), b.json\n')) == [
        'the-run-a-bjson',
        'the-run-a-bjson-1',
    ]


def test_the_name_check_sees_a_moved_module_and_a_missing_file():
    assert dangling_names('`gsp_calibrator.collection.protocol.CollectionProtocol`') == []
    assert dangling_names('`gsp_calibrator.protocol.CollectionProtocol`') == [
        'gsp_calibrator.protocol.CollectionProtocol'
    ]
    assert dangling_names('`src/gsp_calibrator/gsp_calibrator/{calibration,settings}.py`') == [
        'src/gsp_calibrator/gsp_calibrator/calibration.py'
    ]


# --- names in docstrings -------------------------------------------------------------------------

#: Every Python file of the project whose docstrings are checked: the packages and their tests,
#: the cross-package tests and the scripts.
PYTHON_FILES = sorted(
    [
        *SRC.glob('*/gsp_*/**/*.py'),
        *SRC.glob('*/test/**/*.py'),
        *(WS / 'test').glob('*.py'),
        *(WS / 'test_support').glob('*.py'),
        *BENCH.glob('**/*.py'),
    ]
)
#: The tests' shared support module (test_support/, not installed).
TEST_SUPPORT_MODULE = 'gsp_testing'
TEST_SUPPORT_FILE = WS / 'test_support' / 'gsp_testing.py'
_ROLE = re.compile(r':(?:mod|class|func|meth|data|attr|exc|obj):`~?([^`<>]+?)`')
#: A backticked dotted name in a docstring: ``module.name`` or ``object.attribute``.
_DOTTED = re.compile(r'``([a-z_]\w*(?:\.[A-Za-z_]\w*)+)(?:\(\))?``')
_FILE = re.compile(r'``([A-Za-z_][\w/]*\.py)``|`([A-Za-z_][\w/]*\.py)`')


def _module_name(path):
    """``gsp_calibrator.run.flow`` of ``src/gsp_calibrator/gsp_calibrator/run/flow.py``; None for
    a test file."""
    if path.is_relative_to(BENCH / 'gsp_bench'):
        parts = path.relative_to(BENCH).with_suffix('').parts
    else:
        parts = path.relative_to(SRC).with_suffix('').parts if path.is_relative_to(SRC) else ()
        if len(parts) < 2 or parts[1] != parts[0]:
            return None
        parts = parts[1:]
    return '.'.join(parts[:-1] if parts[-1] == '__init__' else parts)


def _docstrings(tree):
    """The docstrings of a module's tree: its own, its classes' and its functions'."""
    nodes = [tree, *ast.walk(tree)]
    kinds = (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)
    return [ast.get_docstring(node) or '' for node in nodes if isinstance(node, kinds)]


def _top_level_names(tree):
    names = set()
    for node in tree.body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, ast.Assign):
            names.update(getattr(t, 'id', None) for t in node.targets)
            for target in node.targets:
                if isinstance(target, ast.Tuple):
                    names.update(getattr(e, 'id', None) for e in target.elts)
        elif isinstance(node, ast.AnnAssign):
            names.add(getattr(node.target, 'id', None))
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            names.update((a.asname or a.name.split('.')[0]) for a in node.names)
        elif isinstance(node, ast.If):  # e.g. TYPE_CHECKING imports
            names.update(_top_level_names(ast.Module(body=node.body, type_ignores=[])))
    return names - {None}


def _members(tree, class_name):
    """Names defined in class ``class_name`` of ``tree`` (methods, attributes, fields)."""
    for node in tree.body:
        if isinstance(node, ast.ClassDef) and node.name == class_name:
            inner = _top_level_names(ast.Module(body=node.body, type_ignores=[]))
            return inner | {b.id for b in node.bases if isinstance(b, ast.Name)}
    return None


def _bound_names(tree):
    """Every name the module binds anywhere: definitions, assignments, attributes set
    (``self.x = ...``), arguments and imports."""
    names = set(dir(builtins))
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
            names.add(node.id)
        elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
            names.add(node.attr)
        elif isinstance(node, ast.arg):
            names.add(node.arg)
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            names.update((a.asname or a.name.split('.')[0]) for a in node.names)
    return names


def _resolves(target, module, tree):
    """Whether a docstring's reference ``target`` resolves from ``module`` (whose ``tree`` is
    given): a dotted project name, a name relative to the module's package (``.x``), a sibling
    module (``conversions.make_status``) or a name the module binds (``name``, ``Class.member``)."""
    package = module.split('.')[:-1] if module else []
    if module and _module_path(module.split('.')).name == '__init__.py':
        package = module.split('.')
    if target.startswith('.'):
        if module is None or target.lstrip('.') in _bound_names(tree):
            return True  # a name of the module itself (Sphinx's ``.name``)
        dots = len(target) - len(target.lstrip('.'))
        base = package[: len(package) - dots + 1]
        return not dangling_names('.'.join(base) + '.' + target.lstrip('.'))
    head = target.split('.')[0]
    if head == TEST_SUPPORT_MODULE:
        name = target.split('.')[1] if '.' in target else ''
        return not name or name in _bound_names(ast.parse(TEST_SUPPORT_FILE.read_text()))
    if head.startswith('gsp_'):
        return head in PACKAGES and not dangling_names(target)
    if package and _module_path([*package, head]) is not None:
        return not dangling_names('.'.join([*package, target]))
    if head not in _bound_names(tree):
        return False
    if '.' in target:
        members = _members(tree, head)
        if members is not None and target.split('.')[1] not in members | _bound_names(tree):
            return False
    return True


#: Every project module's last name and package (``flow``, ``run``...), and the standard and
#: third-party modules docstrings may name (``np.linalg``, ``scipy.optimize``...).
_MODULE_NAMES = {
    part for path in SRC.glob('*/gsp_*/**/*.py') for part in path.with_suffix('').parts[-2:]
} | {'np', 'numpy', 'scipy', 'rclpy', 'os', 'sys', 'math', 'time', 'json', 'yaml', 'mcap'}
_MODULE_NAMES |= {'concurrent', 'builtin_interfaces', 'header'}  # a ROS message's header
_FILE_SUFFIXES = {'py', 'csv', 'json', 'yaml', 'png', 'mcap', 'md', 'tmp', 'msg', 'txt'}
_FILE_NAMES = {path.name for path in WS.glob('**/*.py') if '.venv' not in path.parts}


def dangling_docstring_names(path):
    """The names a file's docstrings give that do not resolve (see :func:`_resolves`), and the
    ``*.py`` files they name that the repository does not hold."""
    tree = ast.parse(path.read_text(encoding='utf-8'))
    module = _module_name(path)
    missing = []
    for text in _docstrings(tree):
        missing += dangling_names(text)
        for target in _ROLE.findall(text):
            if not _resolves(target.strip().rstrip('()'), module, tree):
                missing.append(target)
        for target in _DOTTED.findall(text):
            head, last = target.split('.')[0], target.rpartition('.')[2]
            if last in _FILE_SUFFIXES or head in _MODULE_NAMES:
                continue  # a file name, or a module of the project or a library
            if not _resolves(target, module, tree):
                missing.append(target)
        for pair in _FILE.findall(text):
            name = Path(pair[0] or pair[1]).name
            if name not in _FILE_NAMES:
                missing.append(pair[0] or pair[1])
    return sorted(set(missing))


@pytest.mark.parametrize('path', PYTHON_FILES, ids=lambda path: str(path.relative_to(WS)))
def test_docstrings_name_only_what_exists(path):
    missing = dangling_docstring_names(path)
    assert not missing, f'{path.relative_to(WS)} docstrings name what does not exist: {missing}'


def test_the_docstring_check_sees_a_missing_module_function_and_file(tmp_path):
    stale = tmp_path / 'stale.py'
    stale.write_text(
        '"""See :mod:`gsp_calibrator.run_flow`, ``node_waiting.py``, :func:`absent`,\n'
        '``run_folder.Rows`` and :class:`gsp_calibrator.run.record.RunRecord`."""\n'
    )
    assert dangling_docstring_names(stale) == [
        'absent',
        'gsp_calibrator.run_flow',
        'node_waiting.py',
        'run_folder.Rows',
    ]
