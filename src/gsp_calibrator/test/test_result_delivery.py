"""What the calibrator applies to a controller (``result_delivery``, no ROS graph: its
parameter services are stand-ins): the geometry and every ``geometry.effects.*`` to one that
declares them, the rigid geometry (the effects folded in) and no effect key to one that does
not, as ``controller_effects`` says or (``auto``) as the controller's parameter list says."""

import asyncio
import types

import numpy as np
import pytest

from gsp_calibrator.node.result_delivery import ResultDelivery
from gsp_calibrator.run.rigid import Verdicts
from gsp_kinematics.estimation.rigid_fold import fold_effects
from gsp_kinematics.model.effects import IdentifiedEffects
from gsp_kinematics.model.geometry import default_geometry
from gsp_msgs_py.geometry_parameters import EFFECT_PARAMETER_NAMES

NOMINAL = default_geometry('nominal')
VALUES = np.zeros(24)
VALUES[0:6], VALUES[6:12] = 2e-8, 4e-6  # compliance (m/N), backlash (m)
WITH_EFFECTS = NOMINAL.replace(effects=IdentifiedEffects(VALUES, 40.0, (0.0, 0.0, 0.05)))
RIGID = fold_effects(WITH_EFFECTS)
#: Both geometries accepted (the verdicts are test_rigid_verdict's).
ACCEPTED = Verdicts(types.SimpleNamespace(accepted=True), types.SimpleNamespace(accepted=True))


class Services:
    """The controller's list_parameters and set_parameters_atomically: ``declared`` names (None:
    its list service does not answer); what was set, and whether it was listed."""

    def __init__(self, declared):
        self.declared, self.sent, self.listed = declared, None, False

    async def list(self, node_name, prefix, timeout_s, wait_for):
        self.listed = True
        if self.declared is None:
            return None, f'parameter service /{node_name}/list_parameters unavailable'
        return [name for name in self.declared if name.startswith(prefix + '.')], ''

    async def set(self, node_name, values, timeout_s, wait_for):
        undeclared = sorted(set(values) - set(self.declared or ()))
        if undeclared:
            return False, f'Invalid access to undeclared parameter(s): {undeclared}'
        self.sent = values
        return True, ''


def deliver(services, geometry=WITH_EFFECTS, rigid=RIGID, controller_effects='auto'):
    delivery = ResultDelivery.__new__(ResultDelivery)
    delivery.node = types.SimpleNamespace(get_logger=lambda: types.SimpleNamespace(info=print))
    delivery.publisher = types.SimpleNamespace(publish=lambda message: None)
    delivery.parameter_setter = services
    settings = types.SimpleNamespace(
        apply_result=True,
        platform_node_name='controller',
        topic_timeout=1.0,
        controller_effects=controller_effects,
    )
    return asyncio.run(delivery.deliver(settings, geometry, ACCEPTED, rigid, None))


RIGID_NAMES = [f'geometry.{key}' for key in ('base_joints', 'platform_joints', 'leg_offsets')]
RIGID_NAMES += [
    f'geometry.{key}'
    for key in (
        'device_length',
        'inclinometer_axes_angle',
        'limits.leg_stroke_min',
        'limits.leg_stroke_max',
        'limits.base_joint_max_angle',
        'limits.platform_joint_max_angle',
        'sensors.leg_gain_errors',
        'sensors.inclinometer_offsets',
        'sensors.encoder_offset',
        'sensors.lvdt_gain_error',
    )
]


def test_a_controller_that_declares_the_effects_gets_them_all():
    services = Services(RIGID_NAMES + sorted(EFFECT_PARAMETER_NAMES))
    success, note = deliver(services)
    assert success and note.startswith('applied to /controller'), note
    assert 'effects compensated by the controller: compliance, backlash' in note
    assert set(EFFECT_PARAMETER_NAMES) <= set(services.sent)
    assert services.sent['geometry.effects.joint_offset'] == [0.0] * 6  # none of an earlier one
    np.testing.assert_array_equal(services.sent['geometry.leg_offsets'], NOMINAL.leg_offsets)


@pytest.mark.parametrize('declared', ['rigid geometry', 'some effects'])
def test_a_controller_without_the_effects_gets_the_rigid_geometry(declared):
    names = RIGID_NAMES + (['geometry.effects.compliance'] if declared == 'some effects' else [])
    services = Services(names)
    success, note = deliver(services)
    assert success, note
    assert 'applied the rigid geometry to /controller' in note
    assert 'not compensated: compliance, backlash' in note
    assert not any('.effects.' in name for name in services.sent)
    np.testing.assert_array_equal(services.sent['geometry.leg_offsets'], RIGID.leg_offsets)
    assert np.max(np.abs(RIGID.leg_offsets - NOMINAL.leg_offsets)) > 1e-6


def test_controller_effects_decides_without_asking():
    services = Services(RIGID_NAMES + sorted(EFFECT_PARAMETER_NAMES))
    success, note = deliver(services, controller_effects='rigid')
    assert success and 'controller_effects: rigid' in note and not services.listed
    np.testing.assert_array_equal(services.sent['geometry.leg_offsets'], RIGID.leg_offsets)
    services = Services(RIGID_NAMES)
    success, note = deliver(services, controller_effects='compensated')
    assert not success and 'undeclared' in note and not services.listed


def test_a_rigid_geometry_reaches_a_rigid_controller_and_an_unlisted_one_is_not_applied():
    services = Services(RIGID_NAMES)
    success, note = deliver(services, geometry=NOMINAL, rigid=None)
    assert success and 'rigid: it does not declare' in note, note
    assert sorted(services.sent) == sorted(RIGID_NAMES)
    # No fold (it failed): the geometry without its effects, and the note says so.
    services = Services(RIGID_NAMES)
    success, note = deliver(services, rigid=None)
    assert success and 'not compensated: compliance, backlash' in note, note
    assert sorted(services.sent) == sorted(RIGID_NAMES)
    success, note = deliver(Services(None))
    assert not success
    assert note == 'NOT applied: parameter service /controller/list_parameters unavailable'
