"""DDS domains for test sessions: one per session, never shared on a machine.

Imported by ``conftest.py`` before rclpy is imported anywhere (test/ is on
sys.path), and by the test that checks it.
"""

from __future__ import annotations

import fcntl
from pathlib import Path
import random
import tempfile
from typing import Any

#: Domains a test session may take: 1..101 are valid on every platform with the
#: default port mapping; 0 (the default domain) is left to interactive ROS users.
TEST_DOMAINS = range(1, 102)
_DOMAIN_LOCKS = Path(tempfile.gettempdir()) / 'tiltrov_ros-test-domains'


def claim_domain() -> tuple[int, Any]:
    """A DDS domain no other test session on this machine holds: each session locks
    one (an flock on a file per domain, released when the process ends, however it
    ends), tried in random order. A random pick alone let two sessions run at once
    (a developer's and CI's, or several at once on one machine) meet with a chance
    of a few per cent, and one then recorded the other's topics."""
    _DOMAIN_LOCKS.mkdir(parents=True, exist_ok=True)
    candidates = list(TEST_DOMAINS)
    random.SystemRandom().shuffle(candidates)
    for domain in candidates:
        handle = open(_DOMAIN_LOCKS / f'{domain}.lock', 'a')     # held open: the lock
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            handle.close()
            continue
        return domain, handle
    raise RuntimeError(f'every test DDS domain ({TEST_DOMAINS.start}..{TEST_DOMAINS.stop - 1}) '
                       f'is held by another test session ({_DOMAIN_LOCKS})')
