"""Per-thread caches of the engines' derived tables.

The position-angle search (:mod:`solvers.allocation.driver`) runs its rotations in threads,
each on an effort clock of its own. A table cache shared between them would make a rotation's
work (a table built again after the other rotation evicted it, or found ready), and so the
point where its budget ends, depend on how the threads interleave. Each thread therefore keeps
its own caches: the same call charges the same work whatever the load.
"""

from __future__ import annotations

import threading
from typing import Any

__all__ = ["thread_cache"]

_LOCAL = threading.local()


def thread_cache(name: str) -> dict[Any, Any]:
    """The calling thread's cache called ``name`` (created empty on first use)."""
    caches = getattr(_LOCAL, "caches", None)
    if caches is None:
        caches = _LOCAL.caches = {}
    return caches.setdefault(name, {})
