"""Publishing and applying a calibration result (the ``calibrator`` node; docs/verdict.md)."""

from rcl_interfaces.srv import ListParameters, SetParametersAtomically
from rclpy.parameter import Parameter
from std_msgs.msg import String

from gsp_calibrator.run.host import WAIT_OK
from gsp_calibrator.run.response import RESULT_COMMENT
from gsp_kinematics.model.geometry import geometry_to_parameters, geometry_to_yaml
from gsp_msgs_py.geometry_parameters import EFFECT_PARAMETER_NAMES, EFFECT_PARAMETER_PREFIX


class ResultDelivery:
    """Publishes results on ``publisher`` (latched) and applies them from ``node``."""

    def __init__(self, node, publisher, callback_group=None):
        self.node = node
        self.publisher = publisher
        self.parameter_setter = ParameterSetter(node, callback_group)

    async def deliver(self, settings, geometry, verdicts, rigid, wait_for):
        """Publish ``geometry``; with ``apply_result``, apply it (or ``rigid``, the effects folded
        in, to a controller that does not compensate them) when the verdict of what the
        controller runs accepts it. ``(success, note)``: ``note`` says what the apply did
        ('' when not asked for or nothing accepted); success: accepted and applied if asked."""
        self.publisher.publish(String(data=geometry_to_yaml(geometry, comment=RESULT_COMMENT)))
        if not (settings.apply_result and verdicts.any_accepted):
            return verdicts.compensating.accepted, ''
        node_name, timeout = settings.platform_node_name, settings.topic_timeout
        compensates, how = await self.compensates(settings, wait_for)
        if compensates is None:
            return False, f'NOT applied: {how}'
        verdict, which = verdicts.of(compensates)
        if not verdict.accepted:
            return False, not_accepted_note(node_name, which, verdict, how)
        if compensates:
            values = geometry_to_parameters(geometry, all_effects=True)
        else:  # no rigid geometry (none was identified, or no fold): no effect key at all
            values = geometry_to_parameters(geometry if rigid is None else rigid)
            values = {k: v for k, v in values.items() if not k.startswith(EFFECT_PARAMETER_PREFIX)}
        applied, why = await self.parameter_setter.set(node_name, values, timeout, wait_for)
        if not applied:
            return False, f'NOT applied: {why}'
        note = applied_note(node_name, geometry, compensates, rigid is not None, how)
        note += verdict_note(geometry, which, compensates)
        self.node.get_logger().info(note)
        return True, note

    async def compensates(self, settings, wait_for):
        """``(True | False, how it was decided)``: whether the controller compensates the effects
        (``controller_effects``); ``(None, why)`` when its parameters could not be listed."""
        if settings.controller_effects != 'auto':
            return settings.controller_effects == 'compensated', 'controller_effects'
        prefix = EFFECT_PARAMETER_PREFIX.rstrip('.')
        names, why = await self.parameter_setter.list(
            settings.platform_node_name, prefix, settings.topic_timeout, wait_for
        )
        if names is None:
            return None, why
        return set(EFFECT_PARAMETER_NAMES) <= set(names), 'auto'


def _why_rigid(decided):
    """Why the controller runs the rigid geometry (``decided``: 'auto' when its parameters told)."""
    if decided == 'auto':
        return 'it does not declare the geometry.effects.* parameters'
    return 'controller_effects: rigid'


def applied_note(node_name, geometry, compensates, folded, decided):
    """What was applied to ``/node_name``: the geometry with its effects, or the rigid one
    (``folded``: the effects folded in)."""
    groups = [group for group in geometry.effects.groups() if group != 'thermal']
    if compensates:
        what = 'geometry.* parameters'
        if groups:
            what += f'; effects compensated by the controller: {", ".join(groups)}'
        if 'thermal' in geometry.effects.groups():
            what += '; the thermal drift reported, not compensated'
        return f'applied to /{node_name} ({what})'
    why = _why_rigid(decided)
    if not folded:
        identified = geometry.effects.groups()
        dropped = f'; not compensated: {", ".join(identified)}' if identified else ''
        return f'applied to /{node_name} (geometry.* parameters, rigid: {why}{dropped})'
    return (
        f'applied the rigid geometry to /{node_name} ({why}): the effects folded in '
        f'(result_rigid.yaml); not compensated: {", ".join(geometry.effects.groups())}'
    )


def verdict_note(geometry, which, compensates):
    """Which geometry the verdict that let ``geometry`` be applied describes ('' if one)."""
    if geometry.effects.none:
        return ''
    if which == 'compensating' and not compensates:  # no fold: no rigid figure either
        return '; the verdict describes the geometry with its effects (no rigid geometry)'
    return f'; the verdict describes the {which} geometry'


def not_accepted_note(node_name, which, verdict, decided):
    """Why nothing was applied to ``/node_name``: the ``verdict`` of the ``which`` geometry it
    runs does not accept it."""
    runs = 'the geometry with its effects (result.yaml)'
    if which == 'rigid':
        runs = f'the rigid geometry (result_rigid.yaml): {_why_rigid(decided)}'
    return (
        f'NOT applied to /{node_name}: it runs {runs}, and the verdict of the {which} '
        f'geometry does not accept it: {"; ".join(verdict.failures)}'
    )


class ParameterSetter:
    """Sets other nodes' parameters atomically from ``node`` (one cached client per service)."""

    def __init__(self, node, callback_group=None):
        self.node = node
        self.callback_group = callback_group
        self._clients = {}

    def _client(self, kind, node_name, name):
        """``(client, service)`` of ``/<node_name>/<name>`` (a ``kind`` service)."""
        service = f'/{node_name.lstrip("/")}/{name}'
        if service not in self._clients:
            self._clients[service] = self.node.create_client(
                kind, service, callback_group=self.callback_group
            )
        return self._clients[service], service

    async def set(self, node_name, values, timeout_s, wait_for):
        """Set ``values`` ({name: value}) on ``/<node_name>``; ``(True, '')`` or ``(False, why)``."""
        client, service = self._client(
            SetParametersAtomically, node_name, 'set_parameters_atomically'
        )
        request = SetParametersAtomically.Request()
        request.parameters = [
            Parameter(name, value=value).to_parameter_msg() for name, value in values.items()
        ]
        response, why = await call_service(client, service, request, timeout_s, wait_for)
        if response is None:
            return False, why
        if not response.result.successful:
            return False, f'{service} refused the geometry: {response.result.reason}'
        return True, ''

    async def list(self, node_name, prefix, timeout_s, wait_for):
        """The names of ``/<node_name>``'s parameters under ``prefix``: ``(names, '')`` or
        ``(None, why)``."""
        client, service = self._client(ListParameters, node_name, 'list_parameters')
        request = ListParameters.Request(
            prefixes=[prefix], depth=ListParameters.Request.DEPTH_RECURSIVE
        )
        response, why = await call_service(client, service, request, timeout_s, wait_for)
        return (None, why) if response is None else (list(response.result.names), '')


async def call_service(client, service, request, timeout_s, wait_for):
    """Call ``service`` through ``client``: ``(response, '')`` or ``(None, why)`` (``wait_for``:
    :attr:`gsp_calibrator.run.host.RunHost.wait_for`)."""
    if await wait_for(client.service_is_ready, timeout_s) != WAIT_OK:
        return None, f'parameter service {service} unavailable within {timeout_s:g} s'
    future = client.call_async(request)
    if await wait_for(future.done, timeout_s) != WAIT_OK:
        client.remove_pending_request(future)
        return None, f'no answer from {service} within {timeout_s:g} s'
    return future.result(), ''
