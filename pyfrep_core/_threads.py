"""torch's intra-op thread count for the duration of a long run (training, fitting).

Their small batches run faster on one thread.  With torch's OpenMP backend (the CPU
build used here) the setting belongs to the calling thread: a fit in a workbench
background thread does not slow the main thread's re-meshing, and each run restores
its own thread's setting when it ends.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import torch


@contextmanager
def intra_op_threads(n: int | None) -> Iterator[None]:
    """Run the block with ``torch.set_num_threads(n)`` (None: leave it), then restore the setting.

    >>> before = torch.get_num_threads()
    >>> with intra_op_threads(1):
    ...     torch.get_num_threads()
    1
    >>> torch.get_num_threads() == before
    True
    """
    if n is None:
        yield
        return
    if int(n) < 1:
        raise ValueError(f"thread count must be >= 1, got {n!r}")
    before = torch.get_num_threads()
    if before == int(n):  # already so (a mesher's worker, per kernel call): setting it again is not free
        yield
        return
    torch.set_num_threads(int(n))
    try:
        yield
    finally:
        torch.set_num_threads(before)
