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
* The cache: ``$XDG_CACHE_HOME/tiltrov_ros/numba`` (``~/.cache/...``), else the
  temporary directory, in a subdirectory named by a hash of the core's sources
  (:func:`source_key`; the :data:`KEPT_KEYS` most recently used are kept). Each
  kernel is cached by its place in the package and stamped with that hash
  (:func:`_package_locator`): numba's own cache checks a kernel against its own
  file only, not against the kernels it calls in other modules (an edited
  callee once left a stale caller in the cache), and keys it by its absolute
  path (a colcon install of the same sources compiled everything again). So a
  checkout, its colcon workspace and a read-only install share one cache, and
  an install space never needs to be writable. ``NUMBA_CACHE_DIR`` set by the
  user wins, as it is.
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

#: s: about how long compiling a group takes with an empty cache (2-core machine, one
#: process); loading it from the cache takes milliseconds to a few tenths.
COMPILE_SECONDS = {'allocation': 65, 'plant': 3, 'control': 3, 'visual': 2}

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


#: Source keys whose caches are kept in the default cache directory (several checkouts
#: of different versions on one machine each keep theirs).
KEPT_KEYS = 4


def _keyed(base: Path) -> str:
    """``base/<source key>``, created and marked as used; beyond the :data:`KEPT_KEYS`
    most recently used keys, the others' directories are removed."""
    key = source_key()
    directory = base / key
    directory.mkdir(parents=True, exist_ok=True)
    os.utime(directory)
    others = sorted((d for d in base.iterdir() if d.is_dir() and d.name != key
                     and len(d.name) == len(key)), key=lambda d: d.stat().st_mtime)
    for other in others[:max(0, len(others) - (KEPT_KEYS - 1))]:
        shutil.rmtree(other, ignore_errors=True)
    return str(directory)


def _configure_cache() -> str:
    """Point numba's cache somewhere writable, keyed by the sources, before numba is
    imported: ``NUMBA_CACHE_DIR`` as the user set it, else the user's cache directory."""
    directory = os.environ.get('NUMBA_CACHE_DIR') or _keyed(Path(_user_cache_dir()))
    os.environ['NUMBA_CACHE_DIR'] = directory
    numba = sys.modules.get('numba')
    if numba is not None:                            # imported before us: tell it directly
        numba.config.CACHE_DIR = directory
    return directory


def _install_locator() -> None:
    """Cache this package's kernels by their place in the package and the core's source
    key (:class:`_PackageLocator`), ahead of numba's own locators."""
    try:
        from numba.core import caching
        impl = caching.CacheImpl
        base = caching._CacheLocator
    except (ImportError, AttributeError):      # another numba: its own locators (keyed dir)
        return
    classes: list[Any] = impl._locator_classes
    if not any(getattr(c, '__name__', '') == '_PackageLocator' for c in classes):
        classes.insert(0, _package_locator(base))


def _package_locator(base: type) -> type:
    """numba's cache locator for the kernels of this package.

    numba keys a cached kernel by its file's absolute path and checks it against that
    file's contents only. This locator keys it by its path inside the package and
    stamps it with :func:`source_key`: the same sources installed elsewhere (a colcon
    workspace, a read-only install) load the kernels compiled from a checkout, and a
    change anywhere in the core (a callee in another module, an imported constant)
    makes every cached kernel stale.
    """
    stamp = source_key()

    class _PackageLocator(base):  # type: ignore[misc]
        def __init__(self, py_func: Any, py_file: str, relative: Path) -> None:
            self._lineno = py_func.__code__.co_firstlineno
            self._cache_path = os.path.join(sys.modules['numba'].config.CACHE_DIR,
                                            *relative.parent.parts)

        def get_cache_path(self) -> str:
            return self._cache_path

        def get_source_stamp(self) -> str:
            return stamp

        def get_disambiguator(self) -> str:
            return str(self._lineno)

        @classmethod
        def from_function(cls, py_func: Any, py_file: str) -> Any:
            try:
                relative = Path(py_file).resolve().relative_to(_PACKAGE_DIR)
            except (OSError, ValueError):
                return None                      # not a kernel of this package
            locator = cls(py_func, py_file, relative)
            try:
                locator.ensure_cache_path()
            except OSError:
                return None
            return locator

    return _PackageLocator


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
        _install_locator()
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


def warmup(groups: Iterable[str] | None = None, *, seal: bool = True,
           tell: bool = True) -> float:
    """Compile or load every kernel of ``groups`` (default: all of :data:`GROUPS`) for its
    signatures; returns the seconds it took (0 with the numpy reference).

    Imports the groups' kernel modules first. ``seal``: afterwards a call with
    types not compiled raises instead of compiling. ``tell``: a kernel that must be
    compiled (not loaded) prints one line first (:func:`_told_before_compiling`).
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
    with _told_before_compiling(sorted({k.group for k in chosen if not k.sealed}), tell):
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


@contextmanager
def _told_before_compiling(groups: list[str], tell: bool = True) -> Iterator[None]:
    """Within the block, the first kernel numba must compile (not load from the cache)
    prints one line first on stderr: what, about how long, and that ``tiltrov warmup``
    does it ahead (a cold cache is otherwise a silent minute)."""
    from numba.core import event

    told = not tell

    class Teller(event.Listener):
        def on_start(self, ev: Any) -> None:
            nonlocal told
            if told:
                return
            told = True
            about = sum(COMPILE_SECONDS.get(g, 10) for g in groups)
            print(f'tiltrov_ros: compiling the {", ".join(groups)} kernels into '
                  f'{_STATE.cache_dir} (about {about} s, once per change of the sources; '
                  '`tiltrov warmup` does it ahead)', file=sys.stderr, flush=True)

        def on_end(self, ev: Any) -> None:
            pass

    with event.install_listener('numba:compile', Teller()):
        yield


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
