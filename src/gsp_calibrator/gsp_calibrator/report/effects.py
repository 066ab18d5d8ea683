"""The platform effects of a calibration in its result: the choice of model (``auto``), the
identified effect parameters and the thermal drift (pure; docs/platform_effects.md)."""

import datetime
import math

import numpy as np

from gsp_kinematics.estimation.verdict.model_choice import available_groups
from gsp_kinematics.model.effects import EFFECT_GROUPS, EFFECT_PARAMETER_NAMES
from gsp_kinematics.model.kinematics import inverse_kinematics

#: A leg's drift counts as resolved when it exceeds this many standard deviations.
RESOLVED_SIGMAS = 2.0


def untried_groups(design, count, plain):
    """``{group: why}`` of the effect groups ``auto`` cannot try with the run's ``design``
    (``count`` postures) beside the ``plain`` names."""
    available = available_groups(design, count)
    reasons = {
        'compliance': 'the design has no payload mass',
        'thermal': 'the rows have no times',
        'backlash': 'some leg arrives from one direction only (or the rows have no directions)',
        'joint_offsets': '',
    }
    return {g: reasons[g] for g in EFFECT_GROUPS if g not in available and g not in plain}


def _thermal(result, design, nominal, reference_stamp_s):
    """The thermal drift of each leg at the reference instant (um/min, its standard deviation,
    resolved or not), the warming's time constant and the instant the geometry refers to."""
    rates = np.array(
        [result.effects.get(f'strain_rate{leg}', (0.0, math.nan)) for leg in range(1, 7)]
    )
    lengths = np.mean(inverse_kinematics(nominal, np.asarray(result.poses)), axis=0)
    # The strain rate is the initial one of a first-order warming: at the reference instant
    # it has slowed by exp(-t / tau) (1: a linear growth).
    tau = design.thermal_time_constant_s
    slowed = math.exp(-design.reference_time_s / tau) if tau > 0 else 1.0
    scale = lengths * 60.0 * 1e6 * slowed  # 1/s -> um/min
    drift, deviation = rates[:, 0] * scale, rates[:, 1] * scale
    resolved = np.abs(drift) > RESOLVED_SIGMAS * deviation
    utc = None  # a simulated clock from 0: no date
    if reference_stamp_s > 1e9:
        instant = datetime.datetime.fromtimestamp(reference_stamp_s, datetime.UTC)
        utc = instant.isoformat(timespec='seconds')
    return {
        'drift_um_per_min': drift.tolist(),
        'drift_sd_um_per_min': deviation.tolist(),
        'resolved': resolved.tolist(),
        'mean_drift_um_per_min': float(np.mean(drift)),
        'thermal_time_constant_s': float(tau),
        'reference_time_s': float(design.reference_time_s),
        'reference_stamp_s': float(reference_stamp_s),
        'reference_utc': utc,
        'compensated': False,
    }


def effects_record(result, design, nominal, choice=None, untried=None, reference_stamp_s=0.0):
    """The ``effects`` entry of ``result.json`` (docs/data.md#resultjson); None when neither a
    choice was made nor an effect freed."""
    identified = result.effects if result is not None else {}
    if choice is None and not identified:
        return None
    record = {'model_choice': None, 'groups': [], 'parameters': {}, 'thermal': None}
    if choice is not None:
        record['model_choice'] = {**choice.to_dict(), 'not_tried': dict(untried or {})}
    stems = {stem: (group, unit) for group, (stem, unit, _) in EFFECT_GROUPS.items()}
    for name in EFFECT_PARAMETER_NAMES:
        if name in identified:
            value, deviation = identified[name]
            group, unit = stems[name.rstrip('0123456789')]
            entry = {'estimate': value, 'standard_deviation': deviation, 'unit': unit}
            record['parameters'][name] = entry
            if group not in record['groups']:
                record['groups'].append(group)
    record['payload_mass'] = float(design.payload_mass)
    record['centre_of_mass'] = [float(v) for v in design.centre_of_mass]
    record['payload_assumed'] = payload_assumption(design)
    if 'thermal' in record['groups']:
        record['thermal'] = _thermal(result, design, nominal, reference_stamp_s)
    return record


def payload_assumption(design):
    """What the compliance assumed of the load ('' : the user gave its mass): a reference mass at
    the stated centre of mass, so the compliance is the legs' times the load over it."""
    if not design.payload_assumed:
        return ''
    centre = ', '.join(f'{1e3 * v:g}' for v in design.centre_of_mass)
    return (
        f'payload_mass not given: compliance identified for a reference {design.payload_mass:g} '
        f"kg at ({centre}) mm (payload_centre_of_mass), i.e. each leg's compliance times the "
        "load over it; the controller's compensation holds for the load carried during the run"
    )


def _thermal_text(thermal):
    drifts = ', '.join(
        f'{d:+.2f}' + ('' if resolved else '?')
        for d, resolved in zip(thermal['drift_um_per_min'], thermal['resolved'], strict=True)
    )
    when = thermal['reference_utc'] or f'stamp {thermal["reference_stamp_s"]:.1f} s'
    tau = thermal.get('thermal_time_constant_s', 0.0)
    shape = f'a first-order warming, {tau:g} s, ' if tau > 0 else ''
    return (
        f'thermal drift ({shape}at the reference instant): '
        f'{thermal["mean_drift_um_per_min"]:+.2f} um/min mean, per leg {drifts} '
        f'um/min (? within {RESOLVED_SIGMAS:g} sd); not compensated: the geometry refers to '
        f'{when}, {thermal["reference_time_s"]:.1f} s after the first posture (the last)'
    )


def effects_lines(record):
    """Text lines of an :func:`effects_record` (none without one)."""
    if not record:
        return []
    lines = []
    choice = record.get('model_choice')
    if choice is not None:
        lines.append(f'model (auto): {choice["reason"]}')
        for candidate in choice['candidates']:
            groups = '+'.join(candidate['groups']) or 'plain'
            mark = ' (chosen)' if candidate['chosen'] else ''
            lines.append(
                f'  candidate {groups}: held-out position {_held_out_text(candidate)}'
                f'{_test_text(candidate)}{mark}'
            )
        for group, why in choice['not_tried'].items():
            lines.append(f'  not tried: {group}' + (f' ({why})' if why else ''))
    if record['groups']:
        lines.append(
            f'effects identified: {", ".join(record["groups"])} (payload '
            f'{record["payload_mass"]:g} kg); compensated by the controller except the thermal '
            'drift'
        )
        if 'compliance' in record['groups'] and record.get('payload_assumed'):
            lines.append(record['payload_assumed'])
    if record.get('thermal'):
        lines.append(_thermal_text(record['thermal']))
    if record.get('rigid'):
        lines.append(rigid_text(record['rigid']))
    return lines


def _number(value, spec):
    """``value`` formatted by ``spec``; 'n/a' for NaN (in a record) or None (read from JSON)."""
    return format(value, spec) if value is not None and math.isfinite(value) else 'n/a'


def _held_out_text(candidate, unit=' mm'):
    """A candidate's held-out position error, or 'n/a' and why it was not measured."""
    value = _number(candidate.get('cv_position_mm'), '.4f')
    if value != 'n/a':
        return value + unit
    why = candidate.get('not_judged') or candidate.get('not_measured') or 'not measured'
    return f'n/a ({why})'


def _test_text(candidate):
    """', chi-square drop D (k parameters, p P)' of a candidate against the model it extends
    ('' for the plain model or a failed fit), and the predicted position error without and with
    the groups it adds."""
    delta, p_value = candidate.get('delta_chi2'), candidate.get('p_value')
    if delta is None or p_value is None or not math.isfinite(p_value):
        return ''
    added = candidate.get('added_parameters', 0)
    text = f', chi-square drop {delta:.1f} ({added} parameters, p {p_value:.2g})'
    without, with_ = candidate.get('predicted_without_mm'), candidate.get('predicted_with_mm')
    if without is not None and with_ is not None and math.isfinite(without * with_):
        text += f', predicted {without:.4f} -> {with_:.4f} mm over the workspace'
    return text


def effects_markdown(record):
    """The ``## Platform effects`` section of ``report.md`` (none without a record)."""
    if not record:
        return []
    lines = ['## Platform effects', '']
    choice = record.get('model_choice')
    if choice is not None:
        lines += [f'Model chosen by `auto`: {choice["reason"]}.', '']
        lines += [
            '| candidate groups | held-out position (mm) | chi-square drop, p | chosen |',
            '|---|---|---|---|',
        ]
        for candidate in choice['candidates']:
            groups = ', '.join(candidate['groups']) or 'plain'
            chosen = 'yes' if candidate['chosen'] else ''
            test = _test_text(candidate).removeprefix(', chi-square drop ') or '-'
            held_out = _held_out_text(candidate, unit='')
            lines.append(f'| {groups} | {held_out} | {test} | {chosen} |')
        lines.append('')
        for group, why in choice['not_tried'].items():
            lines.append(f'- not tried: {group}' + (f' ({why})' if why else ''))
        lines.append('')
    if record['parameters']:
        lines += ['| parameter | estimate | standard deviation | unit |', '|---|---|---|---|']
        for name, entry in record['parameters'].items():
            lines.append(
                f'| {name} | {_number(entry["estimate"], ".4g")} '
                f'| {_number(entry["standard_deviation"], ".2g")} | {entry["unit"]} |'
            )
        lines.append('')
    if 'compliance' in record['groups'] and record.get('payload_assumed'):
        lines += [record['payload_assumed'] + '.', '']
    if record.get('thermal'):
        lines += [_thermal_text(record['thermal']), '']
    if record.get('rigid'):
        lines += [rigid_text(record['rigid']) + '.', '']
    return lines


def rigid_text(record):
    """One line of the ``rigid`` entry of an :func:`effects_record` (``run.rigid.rigid_result``):
    what a rigid controller gets, and its predicted accuracy beside the compensated one."""
    if record.get('failure'):
        return f'rigid controller (no geometry.effects.*): {record["failure"]}'
    predicted = record['predicted']
    compensated = record.get('compensated_predicted_position_mm')
    beside = '' if compensated is None else f' (compensating controller {compensated:.3g} mm)'
    return (
        f'rigid controller (no geometry.effects.*): {record["file"]}, the effects folded in: '
        f'predicted {predicted["position_mm"]["mean"]:.3g} mm over the workspace{beside}; '
        f'not compensated: {", ".join(record["not_compensated"])} (the fold against the '
        f'identified model: {predicted["systematic_position_mm"]["mean"]:.3g} mm)'
    )
