"""Calibration input: synchronised images of the board from every camera, from a folder or a bag.

Folder layout: ``DIR/<camera>/<view>.png`` (or .jpg); files with the same stem in different
camera folders are the same instant. Bag: colour (or mono) images on ``<camera>/color/image_raw``
(the rig graph's topics), grouped across cameras by header stamp with the
:class:`~hand_capture.multiview.sync.FrameSynchronizer`, one group kept every
``min_interval_s`` so that a board held still is not counted many times.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from hand_capture.errors import InputError
from hand_capture.multiview.sync import FrameSynchronizer, SyncConfig

__all__ = ["load_views", "views_from_bag", "views_from_folder"]

_IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp")


def load_views(path: str | Path, cameras: Sequence[str] | None = None, *,
               tolerance_s: float = 0.010, min_interval_s: float = 0.5
               ) -> dict[str, list[np.ndarray | None]]:
    """Camera -> grey images (one per view, None where that camera has none) from a folder of
    per-camera image folders or from a bag.

    Raises:
        InputError: nothing usable found; the message says what was looked for.
    """
    p = Path(path)
    if p.is_dir() and not (p / "metadata.yaml").exists():
        return views_from_folder(p, cameras)
    return views_from_bag(p, cameras, tolerance_s=tolerance_s, min_interval_s=min_interval_s)


def views_from_folder(folder: Path, cameras: Sequence[str] | None = None
                      ) -> dict[str, list[np.ndarray | None]]:
    """Images of ``folder/<camera>/<stem>.png`` matched across cameras by file stem."""
    import cv2

    dirs = sorted(d for d in folder.iterdir() if d.is_dir())
    if cameras is not None:
        missing = [c for c in cameras if not (folder / c).is_dir()]
        if missing:
            raise InputError(f"{folder}: no image folder for camera(s) {missing}; found "
                             f"{[d.name for d in dirs]}")
        dirs = [folder / c for c in cameras]
    files = {d.name: {f.stem: f for f in d.iterdir() if f.suffix.lower() in _IMAGE_SUFFIXES}
             for d in dirs}
    files = {c: f for c, f in files.items() if f}
    if not files:
        raise InputError(f"{folder}: expected one folder per camera holding images "
                         f"({', '.join(_IMAGE_SUFFIXES)}), found none")
    stems = sorted(set().union(*(f.keys() for f in files.values())))
    out: dict[str, list[np.ndarray | None]] = {}
    for cam, by_stem in files.items():
        imgs: list[np.ndarray | None] = []
        for s in stems:
            if s not in by_stem:
                imgs.append(None)
                continue
            img = cv2.imread(str(by_stem[s]), cv2.IMREAD_GRAYSCALE)
            if img is None:
                raise InputError(f"camera {cam!r}: cannot read image {by_stem[s]}")
            imgs.append(img)
        out[cam] = imgs
    return out


def views_from_bag(bag: Path, cameras: Sequence[str] | None = None, *,
                   tolerance_s: float = 0.010, min_interval_s: float = 0.5
                   ) -> dict[str, list[np.ndarray | None]]:
    """Synchronised groups of ``<camera>/color/image_raw`` images from a bag."""
    from hand_capture.bag.bagfile import BagReader

    suffix = "/color/image_raw"
    with BagReader(bag) as reader:
        topics = {t.strip("/")[: -len(suffix)]: t for t in reader.topics
                  if t.endswith(suffix) and t.strip("/").count("/") == 2}
        if cameras is not None:
            missing = [c for c in cameras if c not in topics]
            if missing:
                raise InputError(f"{bag}: no {suffix} topic for camera(s) {missing}; found "
                                 f"{sorted(topics)}")
            topics = {c: topics[c] for c in cameras}
        if not topics:
            raise InputError(f"{bag}: no '<camera>{suffix}' topics; the bag has "
                             f"{sorted(reader.topics)}")
        by_topic = {t: c for c, t in topics.items()}
        sync = FrameSynchronizer(list(topics), SyncConfig(tolerance_s=tolerance_s,
                                                          camera_timeout_s=60.0))
        out: dict[str, list[np.ndarray | None]] = {c: [] for c in topics}
        last = -np.inf
        for m in reader.messages():
            cam = by_topic.get(m.topic)
            if cam is None:
                continue
            msg = reader.check(m)
            stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
            for g in sync.push(cam, stamp, msg, m.timestamp_ns * 1e-9):
                if g.stamp - last < min_interval_s:
                    continue
                last = g.stamp
                for c in out:
                    out[c].append(_grey(g.frames[c][1]) if c in g.frames else None)
    if not any(out.values()):
        raise InputError(f"{bag}: no group of images from all of {sorted(topics)} within "
                         f"{tolerance_s * 1e3:.0f} ms of each other")
    return out


def _grey(msg: object) -> np.ndarray:
    """A decoded ``sensor_msgs/Image`` (mono8, rgb8, bgr8) as a grey uint8 array."""
    import cv2

    enc = msg.encoding
    ch = {"mono8": 1, "rgb8": 3, "bgr8": 3}.get(enc)
    if ch is None:
        raise InputError(f"calibration images must be mono8, rgb8 or bgr8, got {enc!r}")
    buf = np.asarray(msg.data, dtype=np.uint8)
    if buf.size < msg.step * msg.height:
        raise InputError(f"image {msg.width}x{msg.height} {enc}: {buf.size} bytes do not "
                         f"hold the pixels")
    rows = buf[: msg.step * msg.height].reshape(msg.height, msg.step)[:, : msg.width * ch]
    if ch == 1:
        return np.ascontiguousarray(rows)
    img = rows.reshape(msg.height, msg.width, 3)
    code = cv2.COLOR_RGB2GRAY if enc == "rgb8" else cv2.COLOR_BGR2GRAY
    return cv2.cvtColor(np.ascontiguousarray(img), code)
