"""One torch thread for tests of small tensors.

On a shared 2-core machine torch's default 2 intra-op threads oversubscribe the CPU when other processes run,
making tiny tests much slower; one thread is fast and deterministic.
"""

from __future__ import annotations

import contextlib

import torch


@contextlib.contextmanager
def one_thread():
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(n)
