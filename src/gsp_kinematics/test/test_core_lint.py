"""The core passes the workspace's ruff configuration (skipped where ruff is not installed)."""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1]


def find_ruff():
    candidate = Path(sys.executable).with_name('ruff')
    return str(candidate) if candidate.is_file() else shutil.which('ruff')


@pytest.mark.skipif(find_ruff() is None, reason='ruff is not installed')
def test_ruff_is_clean():
    root = next((p for p in PACKAGE.parents if (p / 'pyproject.toml').is_file()), PACKAGE)
    completed = subprocess.run(
        [find_ruff(), 'check', '--output-format', 'concise', str(PACKAGE)],
        cwd=root,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert completed.returncode == 0, completed.stdout + completed.stderr
