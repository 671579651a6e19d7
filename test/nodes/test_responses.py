"""Service responses held until the requester is matched (nodes/responses.py)."""

from __future__ import annotations

from typing import Any
import warnings

from rcl_interfaces.srv import GetParameters
from std_srvs.srv import Trigger

from tiltrov_ros.nodes.reference_publisher import ReferencePublisher
from tiltrov_ros.nodes.responses import HeldResponses


def test_a_stack_node_answers_parameter_requests_through_its_held_responses(ros: Any) -> None:
    """A stack node's parameter services go through :class:`HeldResponses` and answer
    a client as before."""
    node = ros.add(ReferencePublisher(context=ros.context))
    wrapped = [s for s in node.services if s.send_response.__name__ == 'send_response'
               and s.send_response.__qualname__.startswith('HeldResponses')]
    assert {s.srv_name.rsplit('/', 1)[-1] for s in wrapped} >= {
        'get_parameters', 'set_parameters', 'list_parameters', 'describe_parameters'}
    client = ros.node('asker').create_client(GetParameters,
                                             f'{node.get_fully_qualified_name()}/get_parameters')
    assert ros.spin_until(lambda: client.service_is_ready(), timeout=60.0)
    future = client.call_async(GetParameters.Request(names=['use_sim_time']))
    assert ros.spin_until(future.done, timeout=60.0)
    assert len(future.result().values) == 1
    assert node.responses.held == [] and node.responses.resent == 0


def test_a_response_rmw_could_not_send_is_sent_again_until_it_goes(ros: Any) -> None:
    """rmw's refusal (rclpy's "failed to send response (timeout)" warning, as rmw_fastrtps
    gives it when the requester's reader is not matched within 100 ms) is injected for the
    first two tries of a real service's response: the response is held, sent again, and
    the client gets it."""
    server = ros.node('server')
    service = server.create_service(Trigger, 'held_trigger',
                                    lambda request, response: Trigger.Response(success=True))
    real_send = service.send_response
    tries = []

    def refused_twice(response: Any, header: Any) -> None:
        tries.append(1)
        if len(tries) <= 2:
            warnings.warn('failed to send response (timeout): client will not receive '
                          'response', RuntimeWarning, stacklevel=1)
            return
        real_send(response, header)

    service.send_response = refused_twice
    held = HeldResponses(server)
    client = ros.node('asker').create_client(Trigger, '/held_trigger')
    assert ros.spin_until(lambda: client.service_is_ready(), timeout=60.0)
    future = client.call_async(Trigger.Request())
    assert ros.spin_until(future.done, timeout=60.0)
    assert future.result().success
    assert len(tries) == 3 and held.resent == 1 and held.held == [] and held.dropped == 0
