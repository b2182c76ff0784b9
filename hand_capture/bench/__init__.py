"""Benchmark output contract shared by every ``hand-suite bench <name>``.

A benchmark module exposes ``run(quick: bool) -> dict``. It prints a readable table with
:func:`print_table` while it runs and returns its figures; the CLI prints that dict as the last
line, one JSON object (see ARCHITECTURE.md). Every benchmark compares against a baseline
measured in the same run, as a ratio, because absolute times drift on shared machines.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np


def print_table(title: str, headers: Sequence[str], rows: Sequence[Sequence[Any]]) -> None:
    """Print an aligned text table (numbers with 4 significant digits)."""

    def fmt(v: Any) -> str:
        if isinstance(v, float):
            return f"{v:.4g}"
        return str(v)

    cells = [[fmt(v) for v in row] for row in rows]
    widths = [max(len(h), *(len(r[i]) for r in cells)) if cells else len(h)
              for i, h in enumerate(headers)]
    print(f"\n{title}")
    print("  ".join(h.ljust(w) for h, w in zip(headers, widths, strict=True)))
    print("  ".join("-" * w for w in widths))
    for r in cells:
        print("  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)))


def time_calls(fn: Callable[[], object], n: int, warmup: int = 3) -> np.ndarray:
    """Wall time of ``n`` calls of ``fn`` after ``warmup`` calls, in seconds, shape (n,)."""
    for _ in range(warmup):
        fn()
    out = np.empty(n)
    for i in range(n):
        t0 = time.perf_counter()
        fn()
        out[i] = time.perf_counter() - t0
    return out


def json_line(figures: dict[str, Any]) -> str:
    """The last line of a benchmark: one JSON object; NaN/Inf become null."""

    def clean(v: Any) -> Any:
        if isinstance(v, (float, np.floating)):
            v = float(v)
            return v if math.isfinite(v) else None
        if isinstance(v, np.integer):
            return int(v)
        if isinstance(v, dict):
            return {k: clean(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [clean(x) for x in v]
        return v

    return json.dumps(clean(figures), separators=(", ", ": "))
