"""How the compiled kernels are compiled (numba): once, for one explicit signature, with the
GIL released, cached on disk next to the source when that is possible."""

from __future__ import annotations

from pathlib import Path

from numba import njit

# numba keys its on-disk cache on the source file; a frozen bundle ships no source, and
# asking for a cache there fails at import - compile in memory instead
_CACHE = Path(__file__).exists()


def _compile(fn, signature: str | None = None):
    try:
        return njit(signature, cache=_CACHE, nogil=True)(fn)
    except RuntimeError as exc:  # no writable cache folder (read-only install, no home)
        if "cannot cache" not in str(exc):
            raise
        return njit(signature, cache=False, nogil=True)(fn)


def helper(fn):
    """A helper compiled for the types it is called with (inside the kernels)."""
    return _compile(fn)


def kernel(signature: str):
    """A kernel called from Python: compiled for exactly one signature when this module is
    imported (or loaded from numba's cache), so no call ever compiles; ``[:]`` arrays accept
    any memory layout (decoded frames are strided views)."""
    return lambda fn: _compile(fn, signature)
