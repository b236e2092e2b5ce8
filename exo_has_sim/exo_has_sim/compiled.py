"""numba compilation whose on-disk cache goes stale with every source compiled in.

numba caches a compiled function in its module's ``__pycache__`` (or under ``NUMBA_CACHE_DIR``)
and drops the cache when that module's source changes, but not when the source of a function it
calls changes, whose code it compiled in, nor that of a constant it froze: after an edit of
model.py the integrator would go on running the old model. :func:`compiled` is
``numba.njit(cache=True)`` with numba's source stamp extended by the contents of the modules the
function is declared to compile in (and of those they declare, in turn): an edit of any of them
makes the cache stale, and the function is compiled afresh at its next first call in a process.

Nothing happens on the file system at import: the cache of a function is opened, and the
sources read and hashed, when the function is first compiled in a process (numba's own
``cache=True`` makes the cache directory at import). Where no cache can be kept (no writable
directory, a source that cannot be read), the function is compiled in memory.

Checked with numba 0.68: the cache is a :class:`numba.core.caching.FunctionCache` whose
implementation (its ``_impl_class``) wraps the locator numba chooses (in-tree,
``NUMBA_CACHE_DIR`` or user-wide), set as the dispatcher's ``_cache`` as
``Dispatcher.enable_caching`` does. test_compiled.py checks that an edit of a declared module
recompiles, and that the declarations cover every compiled function called.
"""

from __future__ import annotations

import hashlib
import sys
from collections.abc import Callable, Iterable
from pathlib import Path
from types import ModuleType
from typing import Any, TypeVar, cast

from numba import njit
from numba.core.caching import (
    CompileResultCacheImpl,
    FunctionCache,
    NullCache,
    _Cache,
    _CacheLocator,
)

_F = TypeVar('_F', bound=Callable[..., Any])

#: Per module, the modules its compiled functions were declared to compile in.
_DECLARED: dict[str, set[str]] = {}


def compiled(*inlined: ModuleType, nogil: bool = False) -> Callable[[_F], _F]:
    """Return a decorator that compiles a function with numba, cached on disk.

    Parameters
    ----------
    *inlined : ModuleType
        The modules whose code the function compiles in, besides its own: those of the
        compiled functions it calls, and of the constants it reads (numba freezes them). The
        modules these declare are added in turn; a module's declarations count for all its
        compiled functions.
    nogil : bool
        Release the interpreter's lock while the compiled function runs.

    Returns
    -------
    Callable
        The decorator: ``numba.njit(nogil=nogil)`` with a cache that goes stale when the
        source of the function's module or of any module in ``inlined`` changes.

    """
    def decorate(function: _F) -> _F:
        module = function.__module__
        _DECLARED.setdefault(module, set()).update(m.__name__ for m in inlined)
        dispatcher: Any = njit(nogil=True)(function) if nogil else njit(function)
        dispatcher._cache = _LazyCache(function)
        return cast(_F, dispatcher)

    return decorate


def sources(function: Callable[..., Any]) -> frozenset[Path]:
    """Return the source files an edit of which makes the cache of a compiled function stale.

    Parameters
    ----------
    function : Callable
        A function decorated with :func:`compiled` (or its Python function).

    """
    py_func = getattr(function, 'py_func', function)
    seen: set[str] = set()
    pending = [py_func.__module__]
    while pending:
        name = pending.pop()
        if name not in seen:
            seen.add(name)
            pending.extend(_DECLARED.get(name, ()))
    return frozenset(Path(sys.modules[name].__file__ or '').resolve() for name in seen)


def source_stamp(function: Callable[..., Any]) -> object:
    """Return the stamp that a cached compilation of ``function`` must carry to be used.

    This opens the function's cache (numba may make its directory).
    """
    cache = getattr(function, '_cache', None)
    if not isinstance(cache, _LazyCache):
        msg = f'{function!r} is not compiled with exo_has_sim.compiled.compiled'
        raise TypeError(msg)
    return cache.stamp()


def _digest(files: Iterable[Path]) -> str:
    hasher = hashlib.sha256()
    for path in sorted(files):
        hasher.update(str(path).encode())
        hasher.update(hashlib.sha256(path.read_bytes()).digest())
    return hasher.hexdigest()


class _Locator(_CacheLocator):
    """The locator numba chose for a function, with the digest of its sources in its stamp."""

    def __init__(self, inner: Any, files: frozenset[Path]) -> None:
        self._inner = inner
        self._files = files
        self._py_file = inner._py_file  # numba names it in its warnings

    def ensure_cache_path(self) -> None:
        self._inner.ensure_cache_path()

    def get_cache_path(self) -> str:
        return str(self._inner.get_cache_path())

    def get_source_stamp(self) -> object:
        return self._inner.get_source_stamp(), _digest(self._files)

    def get_disambiguator(self) -> str:
        return str(self._inner.get_disambiguator())


class _Implementation(CompileResultCacheImpl):
    def __init__(self, py_func: Callable[..., Any]) -> None:
        super().__init__(py_func)  # type: ignore[no-untyped-call]
        self._locator = _Locator(self._locator, sources(py_func))


class _FunctionCache(FunctionCache):
    _impl_class = _Implementation


class _LazyCache(_Cache):
    """numba's cache of one function, opened at the function's first compilation."""

    def __init__(self, py_func: Callable[..., Any]) -> None:
        self._py_func = py_func
        self._opened: Any = None
        self._enabled = True

    def _open(self) -> Any:
        if self._opened is None:
            try:
                self._opened = _FunctionCache(self._py_func)  # type: ignore[no-untyped-call]
            except (RuntimeError, OSError):  # no cache directory numba can use, or no source
                self._opened = NullCache()
            if not self._enabled:
                self._opened.disable()
        return self._opened

    def stamp(self) -> object:
        """Return the source stamp of the cache, None for no cache (see :func:`source_stamp`)."""
        opened = self._open()
        return None if isinstance(opened, NullCache) else opened._impl.locator.get_source_stamp()

    @property
    def cache_path(self) -> str | None:
        path = self._open().cache_path
        return None if path is None else str(path)

    def load_overload(self, sig: Any, target_context: Any) -> Any:
        return self._open().load_overload(sig, target_context)

    def save_overload(self, sig: Any, data: Any) -> None:
        self._open().save_overload(sig, data)

    def enable(self) -> None:
        self._enabled = True
        if self._opened is not None:
            self._opened.enable()

    def disable(self) -> None:
        self._enabled = False
        if self._opened is not None:
            self._opened.disable()

    def flush(self) -> None:
        self._open().flush()
