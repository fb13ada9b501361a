"""torch's intra-op thread count for one block of work, restored afterwards.

A closed loop asks the BEM predictor one query per control tick: a thread pool only waits there, so
the loops run on one thread; a fit, a sweep cell or a bench may ask for a given count.  Every such
block goes through :func:`torch_threads`, so that the count is set and restored in one way.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

from bemlearn.errors import ArgumentError

__all__ = ["torch_threads"]


@contextlib.contextmanager
def torch_threads(n: int | None) -> Iterator[None]:
    """Run the block with ``torch.set_num_threads(n)`` and restore the previous count afterwards
    (also when the block raises or is interrupted).

    Args:
        n: threads for the block (≥ 1); ``None`` leaves the count as it is.

    Raises:
        ArgumentError: ``n`` below 1.
    """
    if n is not None and n < 1:
        raise ArgumentError(f"threads: expected a positive integer, got {n}")
    import torch  # here, not at the top: `bemlearn --help` and the model-only paths stay torch-free

    previous = torch.get_num_threads()
    if n is not None:
        torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(previous)
