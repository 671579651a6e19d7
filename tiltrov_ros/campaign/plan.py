"""The runs of a campaign (sample x configuration) and the files that reproduce one.

Everything a run needs is resolved here, on the machine that starts the
campaign: the samples' scenarios, the shipped robot, controller and allocator
files, the gain sets; a task carries a whole
:class:`~tiltrov_ros.core.runner.StackConfig`, so a worker needs the package
but none of the files. No Dask here.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, replace
from pathlib import Path
import shlex
import shutil
from typing import Any, NamedTuple

import yaml

from tiltrov_ros.core.allocation import AllocatorConfig, load_allocator_config
from tiltrov_ros.core.campaign import Bound, CampaignSpec, Configuration, Sample, draw_sample
from tiltrov_ros.core.controllers import ControllerConfig, Gains, load_controller_config
from tiltrov_ros.core.errors import CampaignError, TiltrovError
from tiltrov_ros.core.params import RobotParams, load_control_period, load_robot_params
from tiltrov_ros.core.runner import StackConfig
from tiltrov_ros.core.steady import FULL_CIRCLE

#: The name of a campaign's ``--robot`` file in an exported run's folder.
ROBOT_COPY = 'robot.yaml'
#: The campaign's hold criterion in an exported run's folder (``tiltrov sim --hold``).
HOLD_COPY = 'hold.yaml'


class RunTask(NamedTuple):
    """One run: its id (``s00042-pid-robust``), sample index, configuration name, the
    resolved stack it runs, the hold bounds that apply to it, for the runs that do not
    hold the same stack with servos turning all the way round (evidence beside the
    verdict; None when they already do: :func:`counterfactual`) and the name of the
    hold criterion (the campaign's)."""

    run_id: str
    sample: int
    configuration: str
    config: StackConfig
    bounds: tuple[Bound, ...] = ()
    counterfactual: StackConfig | None = None
    criterion: str = ''


def run_id(sample: int, configuration: str) -> str:
    return f's{sample:05d}-{configuration}'


def counterfactual(config: StackConfig) -> StackConfig | None:
    """``config`` with the servos' range the full circle and nothing else changed, or
    None when it already is."""
    robot = config.robot
    if (robot.tilt_min, robot.tilt_max) == FULL_CIRCLE:
        return None
    return replace(config, robot=replace(robot, tilt_min=FULL_CIRCLE[0],
                                         tilt_max=FULL_CIRCLE[1]))


class Plan:
    """The campaign's configurations resolved against the shipped files."""

    def __init__(self, spec: CampaignSpec, robot_file: Path | None = None) -> None:
        """``robot_file``: the robot every sample starts from (default: the shipped
        config/robot.yaml; the samples' drawn keys and the factors' levels go over it)."""
        self.spec = spec
        self.robot_file = robot_file
        where = spec.source or 'campaign'
        try:
            self.robot = load_robot_params(robot_file)
            self.control_period = load_control_period(robot_file)
            shipped_controller = load_controller_config()
            shipped_allocator = load_allocator_config()
        except (TiltrovError, OSError) as exc:
            raise CampaignError(f'{where}: the shipped parameter files: '
                                f'{" ".join(str(exc).split())}') from exc
        gain_sets = dict(spec.gain_sets)
        self.controllers: dict[str, ControllerConfig] = {}
        self.allocators: dict[str, AllocatorConfig] = {}
        for config in spec.configurations:
            gains = {**_plain(asdict(shipped_controller.gains)), **gain_sets[config.gains]}
            self.controllers[config.name] = ControllerConfig(
                config.controller, Gains.from_mapping(gains, source=where),  # type: ignore[arg-type]
                shipped_controller.switching, where)
            try:
                self.allocators[config.name] = AllocatorConfig.from_mapping(
                    {**_plain(asdict(shipped_allocator)), 'mode': config.allocator},
                    source=where)
            except TiltrovError as exc:
                raise CampaignError(f'{where}: compare.allocators: '
                                    f'{" ".join(str(exc).split())}') from exc

    def stack(self, sample: Sample, configuration: Configuration) -> StackConfig:
        """The stack of one run (:class:`CampaignError` naming the sample if invalid)."""
        where = f'{self.spec.source or "campaign"} (sample {sample.index})'
        scenario = sample.scenario(where)
        try:
            robot = scenario.robot(self.robot)
            if configuration.robot:
                robot = RobotParams.from_mapping({**robot.as_dict(), **dict(configuration.robot)},
                                                 source=f'{where}, {configuration.name}')
        except TiltrovError as exc:
            raise CampaignError(' '.join(str(exc).split())) from exc
        return StackConfig(scenario, robot, self.controllers[configuration.name],
                           self.allocators[configuration.name], self.control_period)

    def tasks(self, samples: Sequence[Sample]) -> list[RunTask]:
        """Every run of ``samples``: sample-major, configurations in the file's order."""
        out = []
        for s in samples:
            for c in self.spec.configurations:
                stack = self.stack(s, c)
                out.append(RunTask(run_id(s.index, c.name), s.index, c.name, stack,
                                   self.spec.bounds(c), counterfactual(stack), self.spec.name))
        return out

    def hold_document(self, configuration: Configuration) -> dict[str, Any]:
        """The campaign's hold criterion for the runs of ``configuration`` as a hold file
        (:func:`~tiltrov_ros.core.campaign.load_hold`): the campaign's name and angle
        unit, and the bounds of its ``hold`` section that apply to the configuration, as
        the file gives them, without the configurations they are limited to."""
        doc: Any = {}
        if self.spec.source is not None and Path(self.spec.source).is_file():
            doc = yaml.safe_load(Path(self.spec.source).read_text(encoding='utf-8'))
        entries = list(doc.get('hold') or []) if isinstance(doc, dict) else []
        kept = [{k: v for k, v in entry.items() if k not in ('controllers', 'allocators',
                                                             'gains')}
                for entry, bound in zip(entries, self.spec.hold) if bound.applies(configuration)]
        return {'name': self.spec.name, 'angle_unit': self.spec.angle_unit, 'hold': kept}

    def export(self, sample: int, configuration: str, folder: Path) -> list[Path]:
        """The files that run ``(sample, configuration)`` again with ``tiltrov sim``:
        scenario.yaml, wrench_controller.yaml, thrust_allocator.yaml, hold.yaml (the
        campaign's hold criterion) and reproduce.sh (one command; its metrics.json lands
        in ``sim/``)."""
        config = self.spec.configuration(configuration)
        drawn = draw_sample(self.spec, sample)
        document = dict(drawn.document)
        if config.robot:        # the factors' levels, over the drawn keys (SI units, rad)
            document['robot'] = {**(document.get('robot') or {}),
                                 **{k: list(v) if isinstance(v, tuple) else v
                                    for k, v in config.robot}}
        folder.mkdir(parents=True, exist_ok=True)
        header = (f'# {run_id(sample, configuration)}: sample {sample} of campaign '
                  f'{self.spec.name} (seed {self.spec.seed}), as `tiltrov campaign` ran it\n')
        controller = self.controllers[configuration]
        ros_controller = {'controller': controller.kind, 'gains': _plain(asdict(controller.gains)),
                          'switching': _plain(asdict(controller.switching))}
        files = {
            'scenario.yaml': document,
            'wrench_controller.yaml': {'wrench_controller': {'ros__parameters': ros_controller}},
            'thrust_allocator.yaml': {'thrust_allocator': {
                'ros__parameters': _plain(asdict(self.allocators[configuration]))}},
            HOLD_COPY: self.hold_document(config),
        }
        written = []
        for name, doc in files.items():
            path = folder / name
            path.write_text(header + yaml.safe_dump(doc, sort_keys=False), encoding='utf-8')
            written.append(path)
        if self.robot_file is not None:
            written.append(folder / ROBOT_COPY)
            shutil.copyfile(self.robot_file, written[-1])
        command = reproduce_command(config, self.robot_file is not None)
        script = folder / 'reproduce.sh'
        script.write_text(f'#!/bin/sh\n{header}cd "$(dirname "$0")" && exec {command} "$@"\n',
                          encoding='utf-8')
        script.chmod(0o755)
        return [*written, script]


def reproduce_command(config: Configuration, robot_file: bool = False) -> str:
    """The ``tiltrov sim`` command of a run, from inside its exported folder
    (``robot_file``: with the campaign's ``--robot`` file, copied as robot.yaml; the
    campaign's hold criterion from hold.yaml, so that metrics.json's ``hold`` is the
    row's)."""
    return shlex.join(['tiltrov', 'sim', '--scenario', 'scenario.yaml',
                       '--controller', config.controller, '--allocator', config.allocator,
                       '--controller-file', 'wrench_controller.yaml',
                       '--allocator-file', 'thrust_allocator.yaml',
                       *(['--robot', ROBOT_COPY] if robot_file else []),
                       '--hold', HOLD_COPY, '--out', 'sim'])


def _plain(values: dict[str, Any]) -> dict[str, Any]:
    """Tuples as lists, for YAML and for the parameter parsers."""
    return {k: list(v) if isinstance(v, tuple) else v for k, v in values.items()}
