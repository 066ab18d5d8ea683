"""The numbers of Rauf & Ryu's tables, from ``data/tables.yaml`` shipped inside this package.

One source of truth: the shipped file (read with :mod:`importlib.resources`), or an explicit file
given by the caller (``gsp_paper --tables PATH``). Nothing outside the package is read.
"""

import importlib.resources
from pathlib import Path

import yaml

#: The shipped tables, as ``load_tables`` reports their source.
SHIPPED = 'gsp_bench/data/tables.yaml'

_NOMINAL_SETS = (1, 2, 3)


def load_tables(path=None):
    """``(tables, source)``: the file at ``path``, else the shipped tables.

    ``source`` is the path read, or :data:`SHIPPED`. Raises ``FileNotFoundError`` for a missing
    ``path`` and ``ValueError`` when the file lacks Table 3.
    """
    if path is None:
        text = (
            importlib.resources.files(__package__)
            .joinpath('data', 'tables.yaml')
            .read_text(encoding='utf-8')
        )
        source = SHIPPED
    else:
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f'{path}: no such tables file')
        text, source = path.read_text(encoding='utf-8'), str(path)
    tables = yaml.safe_load(text)
    try:
        table3(tables)
    except (KeyError, TypeError, ValueError) as error:
        raise ValueError(
            f'{source}: not the paper tables (Table 3 unreadable: {error!r})'
        ) from None
    return tables, source


def table1(tables):
    """Table 1: ``{nominal set: (max, mean, sigma)}`` of the 42 platform-parameter errors, mm."""
    section = tables['table1_platform_parameter_errors_mm']
    return {
        k: tuple(float(section[f'nominal_set_{k}'][key]) for key in ('max', 'mean', 'sigma'))
        for k in _NOMINAL_SETS
    }


def table2(tables):
    """Table 2: ``{nominal set: (D0 mm, gamma deg)}`` of the nominal device values."""
    section = tables['table2_nominal_device_values']
    return {
        k: tuple(
            float(section[f'nominal_set_{k}'][key])
            for key in ('device_length_mm', 'inclinometer_axes_angle_deg')
        )
        for k in _NOMINAL_SETS
    }


def table3(tables):
    """Table 3: ``(initial {position_mm, orientation_deg}, levels [...])``, mm and deg."""
    section = tables['table3_mean_errors_after_calibration']
    levels = [
        {
            key: float(level[key])
            for key in ('angle_noise_deg', 'length_noise_mm', 'position_mm', 'orientation_deg')
        }
        for level in section['levels']
    ]
    if not levels:
        raise ValueError('Table 3 has no noise levels')
    initial = {
        key: float(section['initial_error'][key]) for key in ('position_mm', 'orientation_deg')
    }
    return initial, levels
