"""torch's thread count for a block of work.

Many small tensor operations (the body fit's L-BFGS on one mesh, a network run on one
person) are fastest on one thread; a thread pool only adds contention, and a great deal of
it when another process holds the other cores. numba's OpenMP threading layer (the
collision kernels) also resets the OpenMP thread count that torch reads, so a process that
has run a collision query finds torch on every core unless it says otherwise.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def one_torch_thread() -> Iterator[None]:
    """torch on one thread inside the block, its previous thread count restored after."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)
