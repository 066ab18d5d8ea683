"""gsp_plan: the plan uses the calibrator's selection; the sweep's JSON, table and plot."""

import json

import numpy as np
import pytest

from gsp_calibrator.run import postures
from gsp_calibrator.settings import DEFAULTS
from gsp_calibrator.tools import planning, plans
from gsp_kinematics.model.geometry import default_geometry
from gsp_kinematics.model.sensor_noise import SensorNoise

QUICK = ['--pool-size', '120']


def _read(path):
    def reject(constant):
        raise ValueError(f'non-standard JSON constant {constant}')

    return json.loads(path.read_text(encoding='utf-8'), parse_constant=reject)


def test_plan_json(tmp_path, capsys):
    output = tmp_path / 'plan.json'
    argv = ['--postures', '30', '--pairs-per-posture', '4', '--output', str(output), *QUICK]
    assert planning.main(argv) == 0
    plan = _read(output)
    # The calibrator's default: the 44 and the identifiable sensor errors (group 'extended').
    assert plan['rank'] == plan['parameters'] == 51 and plan['unidentifiable'] == []
    predicted = plan['predicted']
    assert 0 < predicted['position_mm_mean'] <= predicted['position_mm_p95']
    assert 0 < predicted['orientation_deg_mean'] <= predicted['orientation_deg_p95']
    # The physical minimum: 30 x (0.02 s settle + 4 samples / 200 Hz).
    assert plan['calibration_s'] == pytest.approx(30 * (0.02 + 4 / 200))
    # The same postures as the calibrator would command with these settings.
    nominal = default_geometry('nominal')
    sigmas = SensorNoise().averaged([4])
    chosen = postures.choose_postures(nominal, 30, 120, 0, sigmas)
    assert np.allclose(plan['selection']['poses'], chosen.poses)
    out = capsys.readouterr().out
    assert 'rank 51 of 51' in out
    # It says what it assumes: a platform that is exactly the model (docs/verdict.md).
    assert 'exactly the model' in predicted['assumes'] and 'the prediction assumes' in out


def test_more_samples_predict_better_accuracy():
    nominal = default_geometry('nominal')
    design = plans.Design(pool_size=120)
    few = plans.plan(nominal, 30, 1, design)
    many = plans.plan(nominal, 30, 16, design)
    # Averaging 16 samples divides every sigma by 4: the error scales alike.
    ratio = few['predicted']['position_mm_mean'] / many['predicted']['position_mm_mean']
    assert ratio == pytest.approx(4.0, rel=1e-6)


def test_too_few_postures_are_reported_unidentifiable(tmp_path):
    output = tmp_path / 'plan.json'
    assert planning.main(['--postures', '8', '--output', str(output), *QUICK]) == 0
    plan = _read(output)
    assert plan['rank'] < plan['parameters'] and plan['unidentifiable']
    assert plan['predicted'] is None


def test_sweep_writes_table_plot_and_json(tmp_path, capsys):
    output = tmp_path / 'sweep.json'
    argv = [
        '--sweep',
        '--sweep-postures',
        '20,40',
        '--sweep-samples',
        '1,10',
        '--target-position-um',
        '50',
        '--output',
        str(output),
        *QUICK,
    ]
    assert planning.main(argv) == 0
    document = _read(output)
    rows = document['sweep']['rows']
    assert [(r['postures'], r['pairs_per_posture']) for r in rows] == [
        (20, 1),
        (20, 10),
        (40, 1),
        (40, 10),
    ]
    errors = {
        (r['postures'], r['pairs_per_posture']): r['predicted']['position_mm_mean'] for r in rows
    }
    assert errors[(40, 10)] < errors[(20, 10)] < errors[(20, 1)]
    assert errors[(40, 10)] < errors[(40, 1)]
    cheapest = document['target']['cheapest']
    assert cheapest is not None and 1000 * cheapest['predicted']['position_mm_mean'] <= 50
    assert (tmp_path / 'sweep.png').stat().st_size > 10_000
    assert document['plot'] == str(tmp_path / 'sweep.png')
    out = capsys.readouterr().out
    assert 'postures' in out and 'cheapest design meeting the target' in out


def test_bad_input_is_named(tmp_path, capsys):
    with pytest.raises(SystemExit):
        planning.main(['--sigma-leg-lengths-um', '0'])
    assert '--sigma-leg-lengths-um' in capsys.readouterr().err
    assert planning.main(['--geometry', str(tmp_path / 'missing.yaml')]) == 2
    assert 'gsp_plan: error' in capsys.readouterr().err
    assert planning.main(['--postures', '700', '--pool-size', '600']) == 2


def test_run_options_are_the_calibrators_and_checked_as_gsp_demo_checks_them(capsys):
    args = planning.parse_arguments(['--free', 'paper', 'kq1,kq2'])
    assert args.free_parameters == ['paper', 'kq1', 'kq2']
    names = ('posture_count', 'pool_size', 'pairs_per_posture')
    assert [getattr(args, name) for name in names] == [DEFAULTS[name] for name in names]
    for argv, named in ((['--free', 'kq9'], '--free'), (['--postures', '0'], '--postures')):
        with pytest.raises(SystemExit):
            planning.parse_arguments(argv)
        assert named in capsys.readouterr().err


def test_plan_reports_the_route_and_its_platform_time(tmp_path, capsys):
    output = tmp_path / 'plan.json'
    argv = ['--postures', '20', '--pairs-per-posture', '4', '--output', str(output), *QUICK]
    assert planning.main(argv) == 0
    timing = _read(output)['platform_time']
    assert sorted(timing['order']) == list(range(20))
    assert (
        timing['lower_bound_travel_s'] <= timing['travel_s'] <= timing['selection_order_travel_s']
    )
    assert timing['settle_s'] == pytest.approx(20 * 0.02)
    assert timing['sampling_s'] == pytest.approx(20 * 4 / 200)
    assert timing['total_s'] == pytest.approx(
        timing['travel_s'] + timing['settle_s'] + timing['sampling_s']
    )
    assert 'route (selection indices): ' in capsys.readouterr().out


def test_the_target_plan_is_the_quickest_candidate_reaching_the_target(tmp_path, capsys):
    nominal = default_geometry('nominal')
    design = plans.Design(pool_size=120)
    counts = (15, 20, 30)
    reference = plans.plan(nominal, 30, 10, design)
    target_mm = 1.5 * reference['predicted']['position_mm_mean']
    result = plans.target_plan(nominal, target_mm, None, design, counts)
    best = result['plan']
    assert best['predicted']['position_mm_mean'] <= target_mm
    assert best['platform_time']['total_s'] == min(c['platform_s'] for c in result['candidates'])
    assert best['platform_time']['total_s'] < reference['platform_time']['total_s']
    # The fewest samples that reach it: one less would not.
    fewer = plans.plan(nominal, best['postures'], best['pairs_per_posture'] - 1, design)
    assert fewer['predicted']['position_mm_mean'] > target_mm
    # Out of reach: says what the best reaches.
    output = tmp_path / 'target.json'
    argv = ['--target-position-mm', '1e-5', '--target-postures', '15,20', '--output', str(output)]
    assert planning.main([*argv, *QUICK]) == 0
    assert _read(output)['plan'] is None
    assert 'no plan within the pool reaches position 1e-05 mm; the best reaches' in (
        capsys.readouterr().out
    )


def test_a_plan_for_the_effects_adds_revisits_and_bounds_each_group(tmp_path, capsys):
    output = tmp_path / 'plan.json'
    argv = ['--postures', '30', '--pairs-per-posture', '4', '--output', str(output), *QUICK]
    effects = ['--effects', 'thermal', 'backlash', 'compliance', '--revisit-every', '8']
    assert planning.main(argv + effects) == 0
    plan = _read(output)
    entry, timing = plan['effects'], plan['platform_time']
    route = entry['route']
    # The plain route is the plan's own; the reference is revisited after every 8 postures
    # (30 postures: after 8, 16, 24, and at the end) and the legs arrive both ways.
    assert route['plain_s'] == pytest.approx(timing['total_s'])
    assert route['reference_revisits'] == 4 and route['one_way_legs'] == []
    assert route['added_s'] > 0 and route['total_s'] == pytest.approx(
        route['plain_s'] + route['added_s']
    )
    plan_rows = [k for k, kind in zip(route['order'], route['kind'], strict=True) if kind == 'plan']
    assert plan_rows == list(range(30)) and route['postures'] == 34
    found = entry['identifiability']
    assert found['thermal']['identifiable'] and found['backlash']['identifiable']
    assert len(found['thermal']['crb_std']) == 6 and all(s > 0 for s in found['thermal']['crb_std'])
    # Compliance needs the payload the user gives.
    assert 'payload_mass' in found['compliance']['error']
    out = capsys.readouterr().out
    assert 'effects thermal backlash compliance: 4 postures added' in out
