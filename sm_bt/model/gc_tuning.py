"""The cyclic garbage collector around a big model: paused while it is built, and told to leave
alone what a long-running process keeps.

Loading a model of 100,000 nodes, or building a manager over it, makes millions of objects that
live on. Each full pass of the collector walks every one of them, and the passes come more often
as the heap grows (what that cost is measured in docs/performance.md). What is built has no
garbage cycles to find, so the passes find nothing. Paused, the objects are walked once, by the
first collection after the pause.

The pause nests and is shared between threads: the collector runs again when the last pause
ends, and only if it ran when the first began.

:func:`freeze_long_lived` is for a process that keeps its model and manager until it exits
(``sm-bt manager`` calls it once they are built; an application embedding a big model may too).
"""

from __future__ import annotations

import gc
import threading
from collections.abc import Iterator
from contextlib import contextmanager

#: Allocations between young collections once frozen (CPython's default is 700), and young
#: collections between full ones. A request over a big model keeps millions of objects alive until
#: it ends; with the defaults the collector walked them again and again (docs/performance.md).
LONG_RUN_THRESHOLDS = (50_000, 10, 100)

_lock = threading.Lock()
_depth = 0
_was_enabled = False


@contextmanager
def gc_paused() -> Iterator[None]:
    """Keep the cyclic collector off inside the ``with`` block (reference counting still frees)."""
    global _depth, _was_enabled
    with _lock:
        if _depth == 0:
            _was_enabled = gc.isenabled()
            gc.disable()
        _depth += 1
    try:
        yield
    finally:
        with _lock:
            _depth -= 1
            if _depth == 0 and _was_enabled:
                gc.enable()


def freeze_long_lived() -> None:
    """Collect once, then keep every object that exists now out of the collector's passes
    (``gc.freeze()``) and make the passes rarer (:data:`LONG_RUN_THRESHOLDS`). Objects frozen are
    still freed when nothing refers to them; only a garbage cycle among them would stay."""
    gc.collect()
    gc.freeze()
    gc.set_threshold(*LONG_RUN_THRESHOLDS)
