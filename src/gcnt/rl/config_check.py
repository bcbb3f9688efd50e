"""Range checks shared by the algorithm recipe sections (``td3:``, ``ppo:``).

Imported by the recipe loader without torch, so keep this module free of heavy imports.
"""

from __future__ import annotations

import math

#: rule -> (whether a value breaks it, what the error says the value must be)
_RULES = {
    ">= 1": (lambda v: v < 1, "must be >= 1"),
    ">= 0": (lambda v: v < 0, "must be >= 0"),
    "positive finite": (
        lambda v: not (v > 0 and math.isfinite(v)),
        "must be a positive finite number",
    ),
    "[0, 1]": (lambda v: not 0.0 <= v <= 1.0, "must be in [0, 1]"),
    ">= 0 finite": (lambda v: not (v >= 0 and math.isfinite(v)), "must be >= 0 and finite"),
}


def check_range(config: object, rule: str, *keys: str) -> None:
    """A ValueError naming the first of ``keys`` (attributes of ``config``) that breaks
    ``rule`` (one of ``_RULES``)."""
    breaks, what = _RULES[rule]
    for key in keys:
        v = getattr(config, key)
        if breaks(v):
            raise ValueError(f"{key} {what}, got {v}")
