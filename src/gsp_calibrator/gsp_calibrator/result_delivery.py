"""Publishing and applying a calibration result: one module for both (the ``calibrator`` node).

A run that succeeds hands its calibrated geometry to :class:`ResultDelivery`
(``RunHost.deliver_result``). It latches the geometry params-file YAML on
``/gsp/calibrator/result`` and, with ``apply_result``, sets every ``geometry.*`` parameter of
``platform_node_name`` in one ``SetParametersAtomically`` call. A result that is not accepted
(its cross-validated accuracy misses the requirement, docs/verdict.md) is published, never
applied.
"""

from rcl_interfaces.srv import SetParametersAtomically
from rclpy.parameter import Parameter
from std_msgs.msg import String

from gsp_calibrator.run.host import WAIT_OK
from gsp_calibrator.run.identify import RESULT_COMMENT
from gsp_kinematics.geometry import geometry_to_parameters, geometry_to_yaml


class ResultDelivery:
    """Publishes results on ``publisher`` (the latched result topic) and applies them from
    ``node`` (its parameter clients in ``callback_group``)."""

    def __init__(self, node, publisher, callback_group=None):
        self.node = node
        self.publisher = publisher
        self.parameter_setter = ParameterSetter(node, callback_group)

    async def deliver(self, settings, geometry, accepted, wait_for):
        """Publish ``geometry``; apply it if ``settings.apply_result`` and it is ``accepted``
        (it meets the required accuracy). ``(success, note)``: ``note`` says what the apply did
        ('' when it was not asked for); success is False when the result is not accepted, or
        when the apply failed."""
        self.publisher.publish(String(data=geometry_to_yaml(geometry, comment=RESULT_COMMENT)))
        if not (settings.apply_result and accepted):
            return accepted, ''
        node_name = settings.platform_node_name
        applied, why = await self.parameter_setter.set(
            node_name, geometry_to_parameters(geometry), settings.topic_timeout, wait_for
        )
        if not applied:
            return False, f'NOT applied: {why}'
        self.node.get_logger().info(f'calibrated geometry applied to /{node_name}')
        return True, f'applied to /{node_name} (geometry.* parameters)'


class ParameterSetter:
    """Sets other nodes' parameters atomically from ``node`` (one cached client per service)."""

    def __init__(self, node, callback_group=None):
        self.node = node
        self.callback_group = callback_group
        self._clients = {}

    async def set(self, node_name, values, timeout_s, wait_for):
        """Set ``values`` ({name: value}) on ``/<node_name>``; ``(True, '')`` or ``(False, why)``."""
        service = f'/{node_name.lstrip("/")}/set_parameters_atomically'
        if service not in self._clients:
            self._clients[service] = self.node.create_client(
                SetParametersAtomically, service, callback_group=self.callback_group
            )
        return await set_parameters_atomically(
            self._clients[service], service, values, timeout_s, wait_for
        )


async def set_parameters_atomically(client, service, values, timeout_s, wait_for):
    """Set ``values`` ({name: value}) through ``client`` (``SetParametersAtomically`` of
    ``service``); ``(True, '')`` or ``(False, why)``. ``wait_for(predicate, timeout_s)``: a
    future of :data:`.run.host.WAIT_OK` or :data:`.run.host.WAIT_TIMEOUT` (e.g.
    :meth:`.node_threads.Waits.add`)."""
    if await wait_for(client.service_is_ready, timeout_s) != WAIT_OK:
        return False, f'parameter service {service} unavailable within {timeout_s:g} s'
    request = SetParametersAtomically.Request()
    request.parameters = [
        Parameter(name, value=value).to_parameter_msg() for name, value in values.items()
    ]
    future = client.call_async(request)
    if await wait_for(future.done, timeout_s) != WAIT_OK:
        client.remove_pending_request(future)
        return False, f'no answer from {service} within {timeout_s:g} s'
    result = future.result().result
    if not result.successful:
        return False, f'{service} refused the geometry: {result.reason}'
    return True, ''
