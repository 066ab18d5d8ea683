"""``make bench`` (``python -m gsp_bench``): the core's sections (:mod:`.core`) and every other
section, one module each. Output: ``results/bench.json``; ``--help`` lists the skip options.
"""

import sys

from gsp_bench import (
    collection_rate,
    core,
    effects,
    end_to_end,
    model_choice_cpu,
    noise_unknown,
    physics,
    platform_time,
    rigid_fold,
    run_to_requirement,
    run_to_requirement_levers,
    sensor_dynamics,
    sensor_errors,
    settle_ringing,
    upkeep,
    upkeep_realistic,
    verdict,
)

#: ``bench.json`` key -> ``run(quick=bool) -> dict`` of the sections beyond the core's.
EXTRA_SECTIONS = {
    'end_to_end': end_to_end.run,
    'sensor_errors': sensor_errors.run,  # docs/sensor_errors.md
    'noise_unknown': noise_unknown.run,  # docs/sensor_errors.md
    'platform_time': platform_time.run,  # docs/planning.md
    'sensor_dynamics': sensor_dynamics.run,  # docs/sensor_errors.md
    'settle_ringing': settle_ringing.run,  # docs/sensor_errors.md
    'collection_rate': collection_rate.run,  # docs/architecture.md#synchronisation
    'verdict': verdict.run,  # docs/verdict.md
    'upkeep': upkeep.run,  # docs/upkeep.md
    'upkeep_realistic': upkeep_realistic.run,  # docs/upkeep.md
    'effects': effects.run,  # docs/platform_effects.md
    'model_choice_cpu': model_choice_cpu.run,  # docs/platform_effects.md
    'rigid_fold': rigid_fold.run,  # docs/platform_effects.md
    'physics': physics.run,  # docs/physics.md
    'run_to_requirement': run_to_requirement.run,  # docs/upkeep.md
    'run_to_requirement_levers': run_to_requirement_levers.run,  # docs/upkeep.md
}


def main(argv=None):
    """``make bench``; ``argv`` as :func:`gsp_bench.core.main` takes it."""
    return core.main(argv, extra_sections=EXTRA_SECTIONS)


if __name__ == '__main__':
    sys.exit(main())
