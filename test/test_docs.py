"""Generated docs match the code: docs/parameters.md is rendered from the nodes' spec tables."""

import importlib.machinery
import importlib.util
from pathlib import Path

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
