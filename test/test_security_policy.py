"""The SROS2 access-control policy: well-formed and in step with the suite's interfaces.

SROS2 cannot run with the PyPI wheels (their Fast DDS has no security plugins), so the policy is
checked here statically: the element structure of the SROS2 policy format 0.2.0, and every topic
and service of :mod:`gsp_msgs_py.names` granted to the nodes that use it (docs/security.md).
"""

import xml.etree.ElementTree as ElementTree
from pathlib import Path

import pytest

from gsp_msgs_py import names

POLICY = Path(__file__).resolve().parents[1] / 'security' / 'gsp_calibration.policy.xml'

#: Permission lists of a profile and the qualifiers (attributes) each takes.
LISTS = {
    'topics': ('topic', {'publish', 'subscribe'}),
    'services': ('service', {'reply', 'request'}),
    'actions': ('action', {'call', 'execute'}),
}


def _relative(name):
    return name.lstrip('/')


@pytest.fixture(scope='module')
def profiles():
    """``{(enclave, node): {(kind, qualifier): set of names}}`` after checking the structure."""
    root = ElementTree.parse(POLICY).getroot()
    assert root.tag == 'policy' and root.get('version') == '0.2.0'
    assert [child.tag for child in root] == ['contexts']
    table = {}
    for context in root.find('contexts'):
        assert context.tag == 'context' and context.get('path', '').startswith('/gsp_calibration/')
        assert [child.tag for child in context] == ['profiles']
        for profile in context.find('profiles'):
            assert profile.tag == 'profile', profile.tag
            assert profile.get('ns') == '/' and profile.get('node')
            key = (context.get('path'), profile.get('node'))
            assert key not in table, f'profile {key} listed twice'
            grants = table.setdefault(key, {})
            for permission in profile:
                assert permission.tag in LISTS, f'{key}: unknown element <{permission.tag}>'
                item, qualifiers = LISTS[permission.tag]
                assert permission.attrib, f'{key}: <{permission.tag}> without a qualifier'
                assert set(permission.attrib) <= qualifiers, permission.attrib
                assert set(permission.attrib.values()) <= {'ALLOW', 'DENY'}, permission.attrib
                entries = [element.text.strip() for element in permission]
                assert entries and all(e.tag == item for e in permission), key
                for qualifier, value in permission.attrib.items():
                    if value == 'ALLOW':
                        grants.setdefault((permission.tag, qualifier), set()).update(entries)
    return table


def _holders(profiles, kind, qualifier, name):
    return {
        node
        for (_, node), grants in profiles.items()
        if name in grants.get((kind, qualifier), set())
    }


def test_one_enclave_per_node_process(profiles):
    enclaves = {enclave for enclave, _ in profiles}
    for node in (
        names.NODE_PLATFORM_SIM,
        names.NODE_DEVICE_DRIVER,
        names.NODE_CALIBRATOR,
        'replay',
    ):
        assert (f'/gsp_calibration/{node}', node) in profiles
    assert '/gsp_calibration/operator' in enclaves


def test_every_topic_has_a_publisher_and_a_subscriber(profiles):
    for topic in names.TOPIC_TYPES:
        name = _relative(topic)
        assert _holders(profiles, 'topics', 'publish', name), f'nobody may publish {topic}'
        assert _holders(profiles, 'topics', 'subscribe', name), f'nobody may subscribe {topic}'


def test_the_calibrate_service_is_served_by_the_calibrator_only(profiles):
    name = _relative(names.SERVICE_CALIBRATE)
    assert _holders(profiles, 'services', 'reply', name) == {names.NODE_CALIBRATOR}
    assert {'gsp_calibrate_client', 'gsp_demo'} <= _holders(profiles, 'services', 'request', name)


def test_only_the_calibrator_may_set_the_platform_geometry(profiles):
    platform_services = {
        node: {
            s
            for s in grants.get(('services', 'request'), set())
            if s.startswith(f'{names.NODE_PLATFORM_SIM}/')
        }
        for (_, node), grants in profiles.items()
    }
    callers = {node for node, services in platform_services.items() if services}
    assert callers == {names.NODE_CALIBRATOR}
    assert platform_services[names.NODE_CALIBRATOR] == {
        f'{names.NODE_PLATFORM_SIM}/set_parameters_atomically'
    }


def test_streams_are_published_only_by_their_sources(profiles):
    sources = {
        names.TOPIC_LEG_LENGTHS: {names.NODE_PLATFORM_SIM, 'replay'},
        names.TOPIC_INCLINOMETER: {names.NODE_DEVICE_DRIVER, 'replay'},
        names.TOPIC_ENCODER: {names.NODE_DEVICE_DRIVER, 'replay'},
        names.TOPIC_LVDT: {names.NODE_DEVICE_DRIVER, 'replay'},
        names.TOPIC_PLATFORM_STATUS: {names.NODE_PLATFORM_SIM, 'replay'},
        names.TOPIC_POSE_COMMAND: {names.NODE_CALIBRATOR, 'gsp_demo'},
        names.TOPIC_CALIBRATION_RESULT: {names.NODE_CALIBRATOR},
    }
    for topic, nodes in sources.items():
        assert _holders(profiles, 'topics', 'publish', _relative(topic)) == nodes, topic


def test_every_node_that_reports_its_health_may_publish_diagnostics(profiles):
    publishers = _holders(profiles, 'topics', 'publish', _relative(names.TOPIC_DIAGNOSTICS))
    with_profile = {node for _, node in profiles} & set(names.DIAGNOSED_NODES)
    assert with_profile and with_profile <= publishers
