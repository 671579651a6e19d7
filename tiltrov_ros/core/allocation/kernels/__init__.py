"""The allocator's compiled kernels (numba), below :class:`..allocator.ThrustAllocator`.

Python ends at :mod:`..allocator`: it checks the arguments, packs them into the
flat float arrays of :mod:`.layout` and, when :func:`tiltrov_ros.core.jit.compiled`,
calls one kernel per ``allocate`` (or per batch) instead of the numpy reference
(the other modules of :mod:`tiltrov_ros.core.allocation`), which stays the
readable implementation the kernels are tested against. Each kernel module
mirrors one reference module and names it.
"""
