"""The docs match the code: docs/parameters.md is rendered from the nodes' spec tables, and every
source path and module name the README and docs/ give exists."""

import ast
import importlib.machinery
import importlib.util
import re
from pathlib import Path

import pytest

WS = Path(__file__).resolve().parents[1]
SCRIPT = WS / 'scripts' / 'gen-parameter-docs'


def _generator():
    loader = importlib.machinery.SourceFileLoader('gen_parameter_docs', str(SCRIPT))
    module = importlib.util.module_from_spec(importlib.util.spec_from_loader(loader.name, loader))
    loader.exec_module(module)
    return module


def test_parameter_docs_match_the_spec_tables():
    generator = _generator()
    assert generator.OUTPUT.read_text() == generator.render(), (
        f'docs/parameters.md is out of date: run `{generator.COMMAND}` and commit the result'
    )


# --- names in the docs ---------------------------------------------------------------------------

DOCS = [WS / 'README.md', *sorted((WS / 'docs').glob('*.md'))]
SRC = WS / 'src'
PACKAGES = sorted(path.name for path in SRC.glob('*/gsp_*') if (path / '__init__.py').is_file())


def _expand(path):
    """``a/{b,c}.py`` -> ``a/b.py``, ``a/c.py`` (one brace group)."""
    head, brace, rest = path.partition('{')
    if not brace:
        return [path]
    choices, _, tail = rest.partition('}')
    return [f'{head}{choice}{tail}' for choice in choices.split(',')]


def _module_path(parts):
    """The source file (or package folder) of module ``parts`` under src/, or None."""
    base = SRC / parts[0] / parts[0]
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
    """Source paths and dotted module names in ``text`` that do not exist in src/."""
    missing = []
    for path in re.findall(r'`(src/[^`\s]+)`', text):
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
    missing = dangling_names(doc.read_text(encoding='utf-8'))
    assert not missing, f'{doc.name} names what src/ does not hold: {missing}'


def test_the_name_check_sees_a_moved_module_and_a_missing_file():
    assert dangling_names('`gsp_calibrator.collection.protocol.CollectionProtocol`') == []
    assert dangling_names('`gsp_calibrator.protocol.CollectionProtocol`') == [
        'gsp_calibrator.protocol.CollectionProtocol'
    ]
    assert dangling_names('`src/gsp_calibrator/gsp_calibrator/{calibration,settings}.py`') == [
        'src/gsp_calibrator/gsp_calibrator/calibration.py'
    ]
