"""The optional stacks of the package (pyproject extras): one clear error when a feature needs a missing one.

``sd15``: diffusers, transformers, peft (the paper's SD1.5 + ControlNet-tile repair, its LoRA, the compact
model's LoRA option, the monocular depth prior); ``ray``: Ray (``go-pipeline batch``). The default path
(`go-pipeline run`, the compact repair model) needs neither.
"""

from __future__ import annotations

import importlib.util

from go_core.errors import GoError

EXTRAS = {"sd15": ("diffusers", "transformers", "peft"), "ray": ("ray",)}


def missing_modules(extra: str) -> list[str]:
    """The modules of ``extra`` that are not installed."""
    return [m for m in EXTRAS[extra] if importlib.util.find_spec(m) is None]


def require_extra(extra: str, feature: str) -> None:
    """Raise one GoError naming the extra and its install command when ``feature`` cannot run here."""
    missing = missing_modules(extra)
    if missing:
        raise GoError(
            f"{feature} needs the optional package(s) {', '.join(missing)}: "
            f"pip install 'go-pipeline[{extra}]'"
        )
