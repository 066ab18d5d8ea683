"""File helpers shared by every layer: atomic writes (temporary file, fsync, ``os.replace``) and
strict JSON (NaN and infinities become ``null``); pure, no rclpy."""

import json
import math
import os
import tempfile
from pathlib import Path

import numpy as np


def atomic_write_bytes(path, data):
    """Write ``data`` to ``path`` atomically; returns the path (a ``Path``)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temporary = tempfile.mkstemp(prefix=f'.{path.name}.', suffix='.tmp', dir=path.parent)
    try:
        with os.fdopen(handle, 'wb') as stream:
            stream.write(data)
            stream.flush()
            os.fsync(stream.fileno())
        os.chmod(temporary, 0o644)
        os.replace(temporary, path)
    except BaseException:
        try:
            os.unlink(temporary)
        except FileNotFoundError:
            pass
        raise
    return path


def atomic_write_text(path, text):
    """Write UTF-8 ``text`` to ``path`` atomically."""
    return atomic_write_bytes(path, text.encode('utf-8'))


def atomic_copy(source, target):
    """Copy the file ``source`` to ``target`` atomically."""
    return atomic_write_bytes(target, Path(source).read_bytes())


def json_safe(value):
    """A copy of ``value`` that strict JSON accepts (numpy to Python, paths to strings, tuples to
    lists, non-finite floats to None)."""
    if isinstance(value, dict):
        return {str(key): json_safe(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(item) for item in value]
    if isinstance(value, np.ndarray):
        return json_safe(value.tolist())
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        value = float(value)
        return value if math.isfinite(value) else None
    if isinstance(value, Path):
        return str(value)
    return value


def to_json(value):
    """Strict, indented JSON text of ``value`` (see :func:`json_safe`), ending in a newline."""
    return json.dumps(json_safe(value), indent=2, allow_nan=False) + '\n'


def write_json(path, value):
    """Write ``value`` as strict JSON to ``path`` atomically."""
    return atomic_write_text(path, to_json(value))


def yaml_float(value):
    """``repr`` of a float that YAML 1.1 (and a ROS ``-p`` argument) reads back as a float:
    ``1e-08`` would be a string, ``1.0e-08`` is not."""
    text = repr(float(value))
    return text.replace('e', '.0e') if 'e' in text and '.' not in text else text
