"""Thrust allocation: a body wrench to four thrusts and two tilts (Section 3 of the paper).

The public API (``ThrustAllocator``, its results and its configuration) is
imported from here; the modules hold one concern each.
"""

from tiltrov_ros.core.allocation.allocator import (
    DEFAULT_WEIGHTS,
    FAILED_WEIGHTS,
    Mode,
    ThrustAllocator,
    allocate_sequence,
)
from tiltrov_ros.core.allocation.config import (
    ALLOCATION,
    ALLOCATOR_YAML,
    AllocatorConfig,
    load_allocator_config,
)
from tiltrov_ros.core.allocation.results import (
    FEASIBILITY_RTOL,
    SHORTFALL_FRACTION,
    AllocationResult,
    BatchResult,
    from_tilts,
    infeasible_rows,
    shortfall_tolerances,
)

__all__ = [
    'ALLOCATION',
    'ALLOCATOR_YAML',
    'DEFAULT_WEIGHTS',
    'FAILED_WEIGHTS',
    'FEASIBILITY_RTOL',
    'SHORTFALL_FRACTION',
    'AllocationResult',
    'AllocatorConfig',
    'BatchResult',
    'Mode',
    'ThrustAllocator',
    'allocate_sequence',
    'from_tilts',
    'infeasible_rows',
    'load_allocator_config',
    'shortfall_tolerances',
]
