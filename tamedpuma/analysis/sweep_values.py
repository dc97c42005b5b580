"""How many runs a Hydra multirun asks for, from its sweep overrides as text (``a,b,c``,
``range(start, stop[, step])``, ``[a,b]`` as one value), without importing Hydra."""

from __future__ import annotations

import math
import re

_RANGE = re.compile(r"range\(\s*([^,()]+?)\s*(?:,\s*([^,()]+?)\s*)?(?:,\s*([^,()]+?)\s*)?\)")


def split_values(value: str) -> list[str]:
    """``a,b,[c,d]`` -> ``['a', 'b', '[c,d]']`` (commas inside brackets do not split)."""
    out, depth, cur = [], 0, ""
    for ch in value:
        if ch in "[({":
            depth += 1
        elif ch in "])}":
            depth -= 1
        if ch == "," and depth == 0:
            out.append(cur)
            cur = ""
        else:
            cur += ch
    out.append(cur)
    return out


def value_count(value: str) -> int | None:
    """The values one sweep override stands for: Python's count for ``range(stop)``,
    ``range(start, stop)`` and ``range(start, stop, step)`` (as Hydra's range sweep), the
    comma-separated items otherwise; None for a ``glob(...)`` (its values are the config
    group's)."""
    text = str(value).strip()
    match = _RANGE.fullmatch(text)
    if match:
        args = [float(a) for a in match.groups() if a is not None]
        start, stop, step = ((0.0, args[0], 1.0) if len(args) == 1 else
                             (args[0], args[1], args[2] if len(args) == 3 else 1.0))
        return max(0, math.ceil((stop - start) / step)) if step else None
    if text.startswith("glob("):
        return None
    return len(split_values(text))


def sweep_size(params) -> int | None:
    """The product of :func:`value_count` over the overrides' values (None if one is unknown)."""
    total = 1
    for value in params:
        count = value_count(value)
        if count is None:
            return None
        total *= count
    return total
