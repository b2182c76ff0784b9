"""Time series extracted from a bag (pure: rosbags type store, no rclpy).

Every extractor returns plain numpy arrays; times are bag receive times [s] relative to the
bag's first message, and ``stamp`` is the header stamp the producer kept from its source image.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hand_capture.bag import BagReader


def _stamp_ns(header: object) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


@dataclass
class TopicData:
    """Deserialised messages of one topic: receive times [ns] and messages."""

    msgtype: str
    t_ns: list[int] = field(default_factory=list)
    msgs: list[object] = field(default_factory=list)


@dataclass
class BagData:
    """Every message of a bag grouped by topic (leading slash stripped)."""

    path: Path
    t0_ns: int
    topics: dict[str, TopicData]

    def has(self, *names: str) -> bool:
        """True if every named topic has messages."""
        return all(n in self.topics and self.topics[n].msgs for n in names)

    def rel_s(self, t_ns: Iterable[int]) -> np.ndarray:
        """Receive times relative to the first message [s]."""
        return (np.asarray(list(t_ns), dtype=np.int64) - self.t0_ns) * 1e-9


def load_bag(path: str | Path, skip: Iterable[str] = ()) -> BagData:
    """Read and deserialise every message of ``path`` except topics in ``skip``.

    Raises:
        BagError: the bag cannot be read (see BagReader).
    """
    skip = {s.lstrip("/") for s in skip}
    topics: dict[str, TopicData] = {}
    with BagReader(path) as r:
        for m in r.messages():
            name = m.topic.lstrip("/")
            if name in skip:
                continue
            td = topics.setdefault(name, TopicData(m.msgtype))
            td.t_ns.append(m.timestamp_ns)
            td.msgs.append(r.check(m))
        t0 = r.start_ns
    return BagData(Path(path), t0, topics)


def joint_series(msgs: list[object], names_attr: str, values_attr: str,
                 joints: list[str]) -> np.ndarray:
    """(T, len(joints)) values by joint name; NaN where a message lacks a joint."""
    out = np.full((len(msgs), len(joints)), np.nan)
    col = {j: i for i, j in enumerate(joints)}
    for t, m in enumerate(msgs):
        names = list(getattr(m, names_attr))
        vals = np.asarray(getattr(m, values_attr), dtype=float)
        for n, v in zip(names, vals, strict=False):
            if n in col:
                out[t, col[n]] = v
    return out


def stamps_ns(msgs: list[object]) -> np.ndarray:
    """Header stamps [ns] of messages, shape (T,)."""
    return np.array([_stamp_ns(m.header) for m in msgs], dtype=np.int64)


#: A latency beyond this [ms] means the stamp is on another clock than the receive time (e.g.
#: simulation time), not a slow stage.
SAME_CLOCK_MS = 60_000.0


def latency_ms(td: TopicData) -> tuple[np.ndarray, np.ndarray]:
    """Per distinct header stamp, in receive order: the stamp [ns] and the receive time of
    the first message carrying it minus that stamp [ms].

    A stage that runs faster than its source (a 250 Hz controller following 30 Hz hand
    poses) repeats the source stamp; the stage's latency is when the source first got through.
    """
    t = np.asarray(td.t_ns, dtype=np.int64)
    st = stamps_ns(td.msgs)
    _, first = np.unique(st, return_index=True)
    first.sort()
    return st[first], (t[first] - st[first]) * 1e-6


def match_by_stamp(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Indices (ia, ib) of messages of two topics carrying identical stamps."""
    pos = {int(s): i for i, s in enumerate(b)}
    ia = [i for i, s in enumerate(a) if int(s) in pos]
    return np.array(ia, dtype=int), np.array([pos[int(a[i])] for i in ia], dtype=int)


def positions(msgs: list[object]) -> np.ndarray:
    """(T, 3) positions [m] of PoseStamped messages."""
    return np.array([[m.pose.position.x, m.pose.position.y, m.pose.position.z] for m in msgs])


def max_lift_mm(positions_m: np.ndarray) -> float:
    """Highest rise [mm] of (T, 3) positions [m] above the first one."""
    return float((positions_m[:, 2].max() - positions_m[0, 2]) * 1000.0)


def contact_force_sum(msgs: list[object]) -> np.ndarray:
    """(T,) total contact force magnitude [N] of ContactArray messages."""
    return np.array([sum(float(np.linalg.norm([c.force.x, c.force.y, c.force.z]))
                         for c in m.contacts) for m in msgs])
