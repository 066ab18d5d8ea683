"""The ``physics`` bench section runs end to end (a smoke run: one seed, few postures, faster
legs); its figures are measured by ``make bench`` (docs/physics.md)."""

import math

from gsp_calibrator.tools.bench import main, physics


def test_the_physics_section_runs_one_seed_through_both_backends():
    assert main.EXTRA_SECTIONS['physics'] is physics.run
    section = physics.run(
        seeds=1,
        postures=physics.QUICK_POSTURES,
        validation_postures=3,
        limits=(0.25, 1.0),
        log=lambda message: None,
    )
    assert section['failed_seeds'] == 0, section['per_seed']
    (seed,) = section['per_seed']
    for key in ('true_mm', 'cv_mm', 'inclinometer_noise_ratio', 'platform_time_ratio'):
        assert math.isfinite(seed[key]) and seed[key] > 0, (key, seed)
    # The physics floor (the true geometry as the controller) is the sag: micrometres.
    assert 0.0 < section['floor_mm'] < 0.1
    assert section['true_over_floor'] == seed['true_over_floor']
