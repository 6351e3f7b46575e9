"""Seeds derived in one place: ``derive_seed(seed, *tags)`` and the generators built from it.

Every random draw of the library and the steps comes from a generator made here, from the run's seed and
tags naming the use (``derive_seed(seed, "loo", view_index)``), never from a global RNG. A derived seed is
the same in every process and on every platform (sha256 of the canonical tag list, not Python's ``hash``).
``derive_seed(seed)`` with no tags is ``seed`` itself, so the main stream of a step (the coarse training's
background colours, the hull's samples) is the one the run's ``--seed`` names.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np
    import torch

Tag = int | str

_MASK63 = (1 << 63) - 1


def derive_seed(seed: int, *tags: Tag) -> int:
    """A non-negative 63-bit seed for the use named by ``tags`` (``seed`` itself when there are none).

    Different tags give independent streams: ``derive_seed(s, "loo", 0)`` and ``derive_seed(s, "loo", 1)``
    share nothing, unlike ``s * 1000 + index`` schemes whose streams collide across seeds."""
    if isinstance(seed, bool) or not isinstance(seed, int):
        raise TypeError(f"seed must be an int, got {type(seed).__name__}")
    if not tags:
        return seed
    for t in tags:
        if isinstance(t, bool) or not isinstance(t, (int, str)):
            raise TypeError(f"seed tags must be int or str, got {t!r}")
    text = json.dumps([seed, *tags], separators=(",", ":"), ensure_ascii=True)
    return int.from_bytes(hashlib.sha256(text.encode("ascii")).digest()[:8], "little") & _MASK63


def torch_generator(seed: int, *tags: Tag, device: str = "cpu") -> torch.Generator:
    """A torch generator seeded with ``derive_seed(seed, *tags)``."""
    import torch

    return torch.Generator(device=device).manual_seed(derive_seed(seed, *tags))


def numpy_rng(seed: int, *tags: Tag) -> np.random.Generator:
    """A numpy generator seeded with ``derive_seed(seed, *tags)``."""
    import numpy as np

    return np.random.default_rng(derive_seed(seed, *tags))


@contextmanager
def seeded_torch_init(seed: int, *tags: Tag) -> Iterator[None]:
    """For code that can only draw from torch's global RNG (``nn.Module`` constructors initialising their
    weights): the global CPU RNG is seeded with ``derive_seed(seed, *tags)`` inside the block and restored
    afterwards, so nothing outside sees it."""
    import torch

    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(derive_seed(seed, *tags))
        yield
