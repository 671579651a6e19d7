"""Fixtures of the campaign tests: the tiny campaign file, and its run on a local cluster
(once per session; several tests compare against it)."""

from __future__ import annotations

from pathlib import Path

from campaign_run import TINY, CampaignRun, tiltrov_campaign
import pytest
import yaml


@pytest.fixture(scope='session')
def tiny_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp('campaign') / 'tiny.yaml'
    path.write_text(yaml.safe_dump(TINY, sort_keys=False))
    return path


@pytest.fixture(scope='session')
def local_run(tiny_file: Path, tmp_path_factory: pytest.TempPathFactory) -> CampaignRun:
    """The tiny campaign on a local cluster of two workers (the default kind)."""
    out = tmp_path_factory.mktemp('local') / 'out'
    run = tiltrov_campaign(tiny_file, '--out', out, '--workers', '2')
    assert run.returncode == 0, run.stdout + run.stderr
    return run
