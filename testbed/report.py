"""Reports for people: how numbers are formatted (one place for every table, summary and line)."""
from __future__ import annotations


def fmt(v: object) -> str:
    """A score for a person: 4 significant digits; long lists summarized by their mean."""
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, list) and len(v) <= 4:
        return "[" + ", ".join(fmt(x) for x in v) + "]"
    if isinstance(v, list) and v and all(isinstance(x, (int, float)) for x in v):
        return f"[{len(v)} values, mean {sum(v) / len(v):.4g}]"
    return str(v)
