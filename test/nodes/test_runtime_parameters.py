"""Run-time parameter changes as ``ros2 param set/delete`` make them: through the nodes'
real parameter services (array values arrive as ``array('d')``, a delete as
NOT_SET). A setting either applies or is refused with a reason."""

from __future__ import annotations

from typing import Any

import pytest
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient

from tiltrov_ros.nodes.plant_simulator import PlantSimulator
from tiltrov_ros.nodes.thrust_allocator import ThrustAllocatorNode
from tiltrov_ros.nodes.wrench_controller import WrenchController


def _client(ros: Any, node: Any) -> AsyncParameterClient:
    client = AsyncParameterClient(ros.node(f'{node.get_name()}_param_client'), node.get_name())
    assert ros.spin_until(client.services_are_ready, timeout=15.0)
    return client


def _set(ros: Any, client: AsyncParameterClient, name: str, value: Any) -> Any:
    future = client.set_parameters([Parameter(name, value=value)])
    assert ros.spin_until(future.done, timeout=10.0)
    return future.result().results[0]


def _delete(ros: Any, client: AsyncParameterClient, name: str) -> Any:
    future = client.delete_parameters([name])
    assert ros.spin_until(future.done, timeout=10.0)
    return future.result().results[0]


def test_allocator_weights_set_over_the_service_apply(ros: Any) -> None:
    allocator = ros.add(ThrustAllocatorNode(context=ros.context))
    client = _client(ros, allocator)
    result = _set(ros, client, 'weights', [2.0, 2.0, 10.0, 10.0, 10.0, 2.0])
    assert result.successful, result.reason
    assert allocator.allocator_config.weights == (2.0, 2.0, 10.0, 10.0, 10.0, 2.0)
    assert allocator.allocator.weights.tolist() == [2.0, 2.0, 10.0, 10.0, 10.0, 2.0]
    refused = _set(ros, client, 'weights', [1.0, 2.0])
    assert not refused.successful
    assert refused.reason == "parameter 'weights': got [1.0, 2.0]; allowed: 6 finite numbers > 0"
    assert allocator.allocator_config.weights == (2.0, 2.0, 10.0, 10.0, 10.0, 2.0)


@pytest.mark.parametrize('cls', [ThrustAllocatorNode, PlantSimulator],
                         ids=['thrust_allocator', 'plant_simulator'])
def test_deleting_a_parameter_is_refused_and_later_sets_work(ros: Any, cls: type) -> None:
    node = ros.add(cls(context=ros.context))
    client = _client(ros, node)
    deleted = _delete(ros, client, 'failed_thrusters')
    assert not deleted.successful
    assert deleted.reason == 'failed_thrusters cannot be deleted (set a value instead)'
    assert node.has_parameter('failed_thrusters')
    result = _set(ros, client, 'failed_thrusters', [2])
    assert result.successful, result.reason
    failed = node.failed if cls is ThrustAllocatorNode else node.plant.failed_thrusters
    assert failed == (1,)


def test_timeouts_set_at_run_time_apply(ros: Any) -> None:
    controller = ros.add(WrenchController(context=ros.context))
    allocator = ros.add(ThrustAllocatorNode(context=ros.context))
    for node in (controller, allocator):
        client = _client(ros, node)
        assert _set(ros, client, 'input_timeout', 2.5).successful
        assert node.input_timeout == 2.5


def test_use_sim_time_is_refused_at_run_time(ros: Any) -> None:
    controller = ros.add(WrenchController(context=ros.context))
    result = _set(ros, _client(ros, controller), 'use_sim_time', True)
    assert not result.successful and 'fixed at start' in result.reason
    assert not controller.on_sim_time()
