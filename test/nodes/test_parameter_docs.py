"""docs/parameters.md is what the parameter tables give, and the tables are what the
nodes declare."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from tiltrov_ros.core.names import RECORDER
from tiltrov_ros.nodes import parameter_docs
from tiltrov_ros.nodes.bag_recorder import BagRecorder
from tiltrov_ros.nodes.plant_simulator import PlantSimulator
from tiltrov_ros.nodes.reference_publisher import ReferencePublisher
from tiltrov_ros.nodes.thrust_allocator import ThrustAllocatorNode
from tiltrov_ros.nodes.wrench_controller import WrenchController

PAGE = Path(__file__).resolve().parents[2] / 'docs' / 'parameters.md'
CLASSES = {'plant_simulator': PlantSimulator, 'wrench_controller': WrenchController,
           'thrust_allocator': ThrustAllocatorNode, 'reference_publisher': ReferencePublisher,
           'bag_recorder': BagRecorder}


def test_the_committed_page_is_generated_from_the_tables() -> None:
    assert PAGE.read_text(encoding='utf-8') == parameter_docs.render(), (
        'docs/parameters.md differs from the parameter tables: run make docs')


def test_check_mode_tells_a_stale_page(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    page = tmp_path / 'parameters.md'
    page.write_text('# stale\n')
    assert parameter_docs.main(['--check', str(page)]) == 1
    assert 'make docs' in capsys.readouterr().err
    assert parameter_docs.main([str(page)]) == 0
    assert parameter_docs.main(['--check', str(page)]) == 0


@pytest.mark.parametrize('entry', parameter_docs.NODES, ids=lambda e: e.node)
def test_each_node_declares_exactly_its_documented_parameters(ros: Any, tmp_path: Path,
                                                              entry: Any) -> None:
    overrides = {'output': str(tmp_path / 'bag')} if entry.node == RECORDER else {}
    node = ros.add(CLASSES[entry.node](context=ros.context, parameter_overrides=overrides))
    # rclpy's own: use_sim_time, start_type_description_service
    declared = set(node._parameters) - {'use_sim_time', 'start_type_description_service'}
    assert declared == entry.names
    for table in (*entry.tables, *entry.shared):
        for param in table:
            described = node.describe_parameter(table.full_name(param.name))
            assert described.read_only == param.read_only, param.name
            assert described.additional_constraints == param.allowed(), param.name
