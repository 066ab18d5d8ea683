"""``gsp_bench`` (``make bench``): the core's benchmark plus this package's ``end_to_end`` section.

The benchmark itself is :func:`gsp_experiments.bench.main`; this package contributes its section
by calling it (``--skip-end-to-end`` leaves the section out). Output: ``results/bench.json``.
"""

import sys

from gsp_calibrator.tools.bench import (
    collection_rate,
    effects,
    end_to_end,
    model_choice_cpu,
    physics,
    platform_time,
    rigid_fold,
    run_to_requirement,
    run_to_requirement_levers,
    sensor_dynamics,
    settle_ringing,
    upkeep_realistic,
    verdict,
)
from gsp_experiments import bench, bench_noise, bench_sensor_errors, bench_upkeep

#: ``bench.json`` key -> ``run(quick=bool) -> dict`` of the sections this package adds.
EXTRA_SECTIONS = {
    'end_to_end': end_to_end.run,
    'sensor_errors': bench_sensor_errors.run,  # docs/sensor_errors.md
    'noise_unknown': bench_noise.run,  # docs/sensor_errors.md
    'platform_time': platform_time.run,  # docs/planning.md
    'sensor_dynamics': sensor_dynamics.run,  # docs/sensor_errors.md
    'settle_ringing': settle_ringing.run,  # docs/sensor_errors.md
    'collection_rate': collection_rate.run,  # docs/architecture.md#synchronisation
    'verdict': verdict.run,  # docs/verdict.md
    'upkeep': bench_upkeep.run,  # docs/upkeep.md
    'upkeep_realistic': upkeep_realistic.run,  # docs/upkeep.md
    'effects': effects.run,  # docs/platform_effects.md
    'model_choice_cpu': model_choice_cpu.run,  # docs/platform_effects.md
    'rigid_fold': rigid_fold.run,  # docs/platform_effects.md
    'physics': physics.run,  # docs/physics.md
    'run_to_requirement': run_to_requirement.run,  # docs/upkeep.md
    'run_to_requirement_levers': run_to_requirement_levers.run,  # docs/upkeep.md
}


def main(argv=None):
    """Console script ``gsp_bench``; ``argv`` as :func:`gsp_experiments.bench.main` takes it."""
    return bench.main(argv, extra_sections=EXTRA_SECTIONS)


if __name__ == '__main__':
    sys.exit(main())
