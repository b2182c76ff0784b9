"""Compare two bags message by message: types, payloads, order and relative timing."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hand_capture.bag.bagfile import BagReader


@dataclass(frozen=True)
class BagComparison:
    """Result of :func:`compare_bags`.

    ``timing_err_ms`` holds, for every matched message, the difference between its time since
    the first message in bag B and in bag A [ms], after removing the mean offset of each topic's
    first message (discovery delays shift a whole topic, not its inner timing).
    """

    counts_a: dict[str, int]
    counts_b: dict[str, int]
    types_equal: bool
    payloads_equal: bool
    mismatches: list[str] = field(default_factory=list)
    timing_err_ms: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def same_messages(self) -> bool:
        """Same topics, types, counts and payloads in the same order."""
        return (self.counts_a == self.counts_b and self.types_equal and self.payloads_equal)

    @property
    def max_timing_err_ms(self) -> float:
        """Largest relative-timing error [ms] (0 for empty bags)."""
        return float(np.abs(self.timing_err_ms).max()) if self.timing_err_ms.size else 0.0


def same_cdr(a: bytes, b: bytes) -> bool:
    """True if two CDR payloads hold the same message.

    DDS implementations pad a serialised message with up to 3 zero bytes to a multiple of 4;
    rosbags does not. Payloads that differ only by that trailing padding are the same message.
    """
    if a == b:
        return True
    short, long_ = (a, b) if len(a) < len(b) else (b, a)
    return len(long_) - len(short) <= 3 and long_.startswith(short) and not any(
        long_[len(short):])


def compare_bags(a: str | Path, b: str | Path) -> BagComparison:
    """Compare bag ``b`` (e.g. a re-recording) with bag ``a`` (the original)."""
    with BagReader(a) as ra, BagReader(b) as rb:
        ta, tb = ra.topics, rb.topics
        msgs_a = list(ra.messages())
        msgs_b = list(rb.messages())
    mismatches: list[str] = []
    types_equal = ta == tb
    if not types_equal:
        mismatches.append(f"topics/types differ: {ta} vs {tb}")
    counts_a: dict[str, int] = {}
    counts_b: dict[str, int] = {}
    for m in msgs_a:
        counts_a[m.topic] = counts_a.get(m.topic, 0) + 1
    for m in msgs_b:
        counts_b[m.topic] = counts_b.get(m.topic, 0) + 1
    payloads_equal = True
    errs: list[float] = []
    t0a = msgs_a[0].timestamp_ns if msgs_a else 0
    t0b = msgs_b[0].timestamp_ns if msgs_b else 0
    for topic in sorted(set(counts_a) | set(counts_b)):
        sa = [m for m in msgs_a if m.topic == topic]
        sb = [m for m in msgs_b if m.topic == topic]
        if len(sa) != len(sb):
            mismatches.append(f"{topic}: {len(sa)} vs {len(sb)} messages")
        for i, (ma, mb) in enumerate(zip(sa, sb, strict=False)):
            if not same_cdr(ma.data, mb.data):
                payloads_equal = False
                mismatches.append(f"{topic}: payload #{i} differs")
                break
        da = np.array([m.timestamp_ns - t0a for m in sa[: len(sb)]], dtype=np.int64)
        db = np.array([m.timestamp_ns - t0b for m in sb[: len(sa)]], dtype=np.int64)
        errs.extend(((db - da) * 1e-6).tolist())
    e = np.asarray(errs)
    if e.size:
        e = e - np.median(e)  # the common start offset is not a timing error
    return BagComparison(counts_a, counts_b, types_equal, payloads_equal, mismatches, e)
