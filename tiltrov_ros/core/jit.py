"""Compiled kernels: which backend runs, where the compiled code is cached, compiling ahead.

The hot paths of the core (allocation, the plant step, the control laws) exist
twice: the numpy/Python *reference* (the readable implementation the tests
trust) and *kernels* compiled by numba from plain-Python loops, pinned to the
reference by tests. This module is the one place that decides which of the two
runs and that manages numba:

* :func:`backend` -- ``'numba'`` or ``'numpy'``, resolved once per process:
  ``TILTROV_BACKEND=numpy`` forces the reference, ``numba`` requires the
  kernels, ``auto`` (the default) takes numba when it imports and otherwise
  the reference, with one warning on stderr.
* :func:`kernel` -- the decorator of every kernel. With numba it returns a lazy
  ``numba.njit(cache=True, nogil=True, error_model='numpy')`` dispatcher
  (nothing compiles at import); without it the plain Python function.
  ``signatures`` name the types a kernel is called with from Python: only
  those are compiled ahead (kernels called only from other kernels need none).
* :func:`warmup` -- imports the kernel modules of the given groups
  (:data:`GROUPS`), compiles (or loads from the cache) every registered kernel
  of those groups for its signatures, then forbids further compilation (a
  call with other types raises instead of compiling in the middle of a
  control tick). The core objects that call kernels (``Plant``, the
  controllers, the allocator) call it in their constructors; nodes call it
  in their constructor, before they subscribe, and report its time on
  ``/diagnostics``; ``tiltrov warmup`` and ``make install`` call it ahead of
  use.
* :func:`compilations` -- a context manager listing what numba compiles
  meanwhile (the tests' proof that nothing compiles after construction).
* The cache: in the package (``core/__pycache__/numba``) when it is writable (a
  checkout, a venv); in a read-only install (a colcon install space under
  /opt, a system site-packages) in ``$XDG_CACHE_HOME/tiltrov_ros/numba``
  (``~/.cache/...``), else in the temporary directory; each in a subdirectory
  named by a hash of the core's sources (:func:`source_key`). numba checks a
  cached kernel against its own file only, not against the kernels it calls in
  other modules (nor the constants it imports): an edited callee left a stale
  caller in the cache. A new key starts a fresh cache; older keys are removed.
  ``NUMBA_CACHE_DIR`` set by the user always wins, as it is.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
import hashlib
import importlib
import os
from pathlib import Path
import shutil
import sys
import tempfile
import time
from typing import Any, TypeVar

#: Environment variable choosing the backend: ``auto`` (default), ``numba`` or ``numpy``.
BACKEND_ENV = 'TILTROV_BACKEND'
BACKENDS = ('auto', 'numba', 'numpy')

F = TypeVar('F', bound=Callable[..., Any])

#: Warm-up group -> the modules whose import registers its kernels.
GROUPS: dict[str, tuple[str, ...]] = {
    'allocation': ('tiltrov_ros.core.allocation',),
    'plant': ('tiltrov_ros.core.plant_kernels',),
    'control': ('tiltrov_ros.core.control_kernels',),
    'visual': ('tiltrov_ros.core.visual_kernels',),
}

_PACKAGE_DIR = Path(__file__).resolve().parent.parent


@dataclass
class _State:
    backend: str | None = None
    reason: str = ''
    cache_dir: str | None = None
    kernels: list[Registered] = field(default_factory=list)
    warm_seconds: dict[str, float] = field(default_factory=dict)


@dataclass
class Registered:
    """A kernel known to :func:`warmup`: its group, name, dispatcher and signatures."""

    group: str
    name: str
    dispatcher: Any
    signatures: tuple[str, ...]
    sealed: bool = False


_STATE = _State()


def _writable(directory: Path) -> bool:
    """True when numba could write its cache beside sources in ``directory``."""
    cache = directory / '__pycache__'
    target = cache if cache.is_dir() else directory
    return os.access(target, os.W_OK | os.X_OK)


def _user_cache_dir() -> str:
    """A writable directory for the cache when the package directory is not."""
    base = os.environ.get('XDG_CACHE_HOME') or os.path.join(os.path.expanduser('~'), '.cache')
    for candidate in (os.path.join(base, 'tiltrov_ros', 'numba'),
                      os.path.join(tempfile.gettempdir(), f'tiltrov_ros-numba-{os.getuid()}')):
        try:
            os.makedirs(candidate, exist_ok=True)
        except OSError:
            continue
        if os.access(candidate, os.W_OK | os.X_OK):
            return candidate
    raise OSError('no writable directory for the compiled kernels\' cache')


def source_key() -> str:
    """A hash of every source file of the core (names and contents): the kernels and
    all they call or import. 16 hex digits."""
    core = _PACKAGE_DIR / 'core'
    digest = hashlib.sha256()
    for path in sorted(core.rglob('*.py')):
        digest.update(path.relative_to(core).as_posix().encode() + b'\0')
        digest.update(path.read_bytes() + b'\0')
    return digest.hexdigest()[:16]


def _keyed(base: Path) -> str:
    """``base/<source key>``, created; the other keys' directories in ``base`` removed
    (best effort: a cache another checkout still uses is rebuilt there next time)."""
    key = source_key()
    directory = base / key
    directory.mkdir(parents=True, exist_ok=True)
    for other in base.iterdir():
        if other.name != key and other.is_dir() and len(other.name) == len(key):
            shutil.rmtree(other, ignore_errors=True)
    return str(directory)


def _configure_cache() -> str:
    """Point numba's cache somewhere writable, keyed by the sources, before numba is
    imported."""
    if os.environ.get('NUMBA_CACHE_DIR'):
        return os.environ['NUMBA_CACHE_DIR']
    core = _PACKAGE_DIR / 'core'
    if _writable(core):
        directory = _keyed(core / '__pycache__' / 'numba')
    else:
        directory = _keyed(Path(_user_cache_dir()))
    os.environ['NUMBA_CACHE_DIR'] = directory
    if 'numba' in sys.modules:                       # imported before us: tell it directly
        sys.modules['numba'].config.CACHE_DIR = directory
    return directory


def backend() -> str:
    """``'numba'`` or ``'numpy'``: the implementation this process runs (resolved once)."""
    if _STATE.backend is not None:
        return _STATE.backend
    wanted = os.environ.get(BACKEND_ENV, 'auto').strip().lower() or 'auto'
    if wanted not in BACKENDS:
        print(f'tiltrov_ros: {BACKEND_ENV}={wanted!r} is not one of {", ".join(BACKENDS)}: '
              'using the numpy reference', file=sys.stderr)
        _STATE.backend, _STATE.reason = 'numpy', f'{BACKEND_ENV}={wanted!r} not understood'
        return _STATE.backend
    if wanted == 'numpy':
        _STATE.backend, _STATE.reason = 'numpy', f'{BACKEND_ENV}=numpy'
        return _STATE.backend
    try:
        _STATE.cache_dir = _configure_cache()
        import numba
    except (ImportError, OSError) as exc:
        if wanted == 'numba':
            raise ImportError(f'{BACKEND_ENV}=numba but the compiled kernels cannot be '
                              f'used: {exc}') from exc
        print(f'tiltrov_ros: numba is not available ({exc}); running the numpy reference '
              '(slower, same answers). Install numba for the compiled kernels.',
              file=sys.stderr)
        _STATE.backend, _STATE.reason = 'numpy', f'numba unavailable: {exc}'
        return _STATE.backend
    _STATE.backend, _STATE.reason = 'numba', f'numba {numba.__version__}'
    return _STATE.backend


def compiled() -> bool:
    """True when the kernels run (the backend is numba)."""
    return backend() == 'numba'


def describe() -> dict[str, Any]:
    """The backend, why, the cache directory and the warm-up times: for diagnostics and
    a run's ``run_info``."""
    name = backend()
    cache = _STATE.cache_dir if name == 'numba' else None
    return {'backend': name, 'reason': _STATE.reason, 'cache_dir': cache,
            'warmup_seconds': dict(_STATE.warm_seconds)}


def kernel(*signatures: str, group: str = '') -> Callable[[F], F]:
    """Decorate a kernel (see the module docstring).

    ``signatures``: numba type strings of the calls made from Python (compiled
    ahead by :func:`warmup`); ``group``: which warm-up set it belongs to
    (``'allocation'``, ``'plant'``, ``'control'``, ``'visual'``); required with signatures.
    """
    if signatures and not group:
        raise ValueError('a kernel called from Python needs a warm-up group')

    def decorate(fn: F) -> F:
        if not compiled():
            return fn
        import numba
        dispatcher: Any = numba.njit(cache=True, nogil=True, error_model='numpy')(fn)
        _plain_types_from_kernels(dispatcher)
        if signatures:
            _STATE.kernels.append(Registered(group, f'{fn.__module__}.{fn.__qualname__}',
                                             dispatcher, tuple(signatures)))
        out: F = dispatcher
        return out

    return decorate


def _plain_types_from_kernels(dispatcher: Any) -> None:
    """Compile a kernel called from another kernel for its arguments' plain types.

    numba types a constant argument as a literal (``Literal[int](3)``,
    ``Literal[bool](True)``) and compiles the callee once more for every such
    constant (and for a counter's initial value met during type inference):
    that more than doubled the allocation kernels' cold compile. The literal
    still converts to the plain type the kernel is compiled for.
    """
    from numba.core import types

    template = dispatcher.get_call_template
    plain: Callable[[Any], Any] = types.unliteral

    def get_call_template(args: tuple[Any, ...], kws: dict[str, Any]) -> Any:
        return template(tuple(plain(a) for a in args), {k: plain(v) for k, v in kws.items()})

    dispatcher.get_call_template = get_call_template


def registered(groups: Iterable[str] | None = None) -> list[Registered]:
    """The kernels registered so far (of ``groups``, or all)."""
    wanted = None if groups is None else set(groups)
    return [k for k in _STATE.kernels if wanted is None or k.group in wanted]


def warmup(groups: Iterable[str] | None = None, *, seal: bool = True) -> float:
    """Compile or load every kernel of ``groups`` (default: all of :data:`GROUPS`) for its
    signatures; returns the seconds it took (0 with the numpy reference).

    Imports the groups' kernel modules first. ``seal``: afterwards a call with
    types not compiled raises instead of compiling.
    """
    if not compiled():
        return 0.0
    start = time.perf_counter()
    names = tuple(GROUPS) if groups is None else tuple(groups)
    unknown = [g for g in names if g not in GROUPS]
    if unknown:
        raise ValueError(f'unknown kernel group(s) {", ".join(unknown)}; groups: '
                         f'{", ".join(GROUPS)}')
    for group in names:
        for module in GROUPS[group]:
            importlib.import_module(module)
    chosen = registered(names)
    for k in chosen:
        if k.sealed:
            continue
        for sig in k.signatures:
            k.dispatcher.compile(sig)
        if seal:
            k.dispatcher.disable_compile()
            k.sealed = True
    elapsed = time.perf_counter() - start
    key = ','.join(sorted({k.group for k in chosen})) or 'none'
    _STATE.warm_seconds[key] = _STATE.warm_seconds.get(key, 0.0) + elapsed
    return elapsed


def overloads() -> dict[str, int]:
    """Registered kernel -> how many type signatures it has compiled or loaded so far
    (unchanged over a run: nothing was compiled nor loaded during it)."""
    return {k.name: len(k.dispatcher.overloads) for k in _STATE.kernels}


@contextmanager
def compilations() -> Iterator[list[str]]:
    """Within the block, the list of the kernels numba compiles (not those it loads from
    the cache), as ``module.name(argument types)``; always empty with the numpy backend."""
    events: list[str] = []
    if not compiled():
        yield events
        return
    from numba.core import event

    class Recorder(event.Listener):
        def on_start(self, ev: Any) -> None:
            d = ev.data['dispatcher']
            events.append(f'{d.py_func.__module__}.{d.py_func.__qualname__}'
                          f'({", ".join(str(a) for a in ev.data["args"])})')

        def on_end(self, ev: Any) -> None:
            pass

    with event.install_listener('numba:compile', Recorder()):
        yield events
