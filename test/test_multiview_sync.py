"""Frame synchronisation across cameras: independent clocks, jitter, drops, a dead camera."""

from __future__ import annotations

import numpy as np
import pytest

from hand_capture.errors import ConfigError, InputError
from hand_capture.multiview.sync import FrameSynchronizer, SyncConfig

FPS = 20.0  # seed 000's capture rate (sec. 4.1)


def _streams(n_cams: int, n_frames: int, *, offsets_s, jitter_s: float, seed: int = 0,
             drops: dict[int, set[int]] | None = None, stop: dict[int, int] | None = None):
    """Frames (arrival time, camera, stamp, true instant) of cameras that each stamp on their
    own clock (constant offset + jitter), arriving 5-15 ms after their stamp, in arrival order."""
    rng = np.random.default_rng(seed)
    out = []
    for c in range(n_cams):
        for k in range(n_frames):
            if drops and k in drops.get(c, set()):
                continue
            if stop and c in stop and k >= stop[c]:
                continue
            stamp = k / FPS + offsets_s[c] + rng.uniform(-jitter_s, jitter_s)
            out.append((stamp + rng.uniform(0.005, 0.015), f"cam{c}", stamp, k))
    out.sort()
    return out


def _run(sync: FrameSynchronizer, frames):
    groups = []
    for arrival, cam, stamp, k in frames:
        groups += sync.push(cam, stamp, k, now=arrival)
    return groups


def test_groups_frames_of_cameras_with_offsets_and_jitter():
    offsets = [0.0, 0.004, -0.003, 0.002, -0.001, 0.003]
    sync = FrameSynchronizer([f"cam{i}" for i in range(6)], SyncConfig(tolerance_s=0.012))
    groups = _run(sync, _streams(6, 100, offsets_s=offsets, jitter_s=0.001))
    assert len(groups) >= 99  # the very last frames may still wait for partners
    for g in groups:
        assert g.complete
        assert len({k for _, k in g.frames.values()}) == 1  # one true instant per group
        assert g.skew_s <= 0.012
        assert min(s for s, _ in g.frames.values()) <= g.stamp <= max(
            s for s, _ in g.frames.values())
    assert sync.stats.dropped == 0 and sync.stats.incomplete == 0
    assert sync.stats.max_skew_s <= 0.012


def test_a_dropped_frame_drops_that_instant_only():
    drops = {2: {10, 11, 40}, 4: {70}}
    sync = FrameSynchronizer([f"cam{i}" for i in range(6)], SyncConfig(tolerance_s=0.01))
    groups = _run(sync, _streams(6, 100, offsets_s=[0.0] * 6, jitter_s=0.002, drops=drops))
    instants = [next(iter(g.frames.values()))[1] for g in groups]
    for k in (10, 11, 40, 70):
        assert k not in instants
    assert all(g.complete and len({k for _, k in g.frames.values()}) == 1 for g in groups)
    assert len(groups) >= 95
    assert sync.stats.dropped == 5 * 4  # the other cameras' frames of the 4 lost instants


def test_a_camera_that_stops_is_named_and_the_rig_goes_on_degraded():
    cfg = SyncConfig(tolerance_s=0.01, camera_timeout_s=0.3)
    sync = FrameSynchronizer(["cam0", "cam1", "cam2"], cfg)
    groups = _run(sync, _streams(3, 100, offsets_s=[0, 0, 0], jitter_s=0.001, stop={1: 40}))
    assert sync.missing(now=100 / FPS) == ("cam1",)
    degraded = [g for g in groups if not g.complete]
    assert degraded and all(g.missing == ("cam1",) for g in degraded)
    assert all(set(g.frames) == {"cam0", "cam2"} for g in degraded)
    # instants after the timeout keep coming, one group each
    last = [next(iter(g.frames.values()))[1] for g in degraded]
    assert last[-1] >= 98 and last == sorted(last)
    assert sync.stats.incomplete == len(degraded)
    # at most the instants inside the timeout are lost
    assert len(groups) >= 100 - int(cfg.camera_timeout_s * FPS) - 3


def test_a_stalled_host_takes_its_backlog_without_declaring_live_cameras_missing():
    """The process gets no CPU for 0.8 s (longer than the timeout), then takes the frames that
    waited in the middleware one per camera in turn, all at the same receive time: every
    camera is alive, so no group may lack one; a camera that truly stopped is still named."""
    cfg = SyncConfig(tolerance_s=0.01, camera_timeout_s=0.3)
    frames = _streams(3, 60, offsets_s=[0, 0, 0], jitter_s=0.001)
    stall = (1.0, 1.8)  # receive times [s] during which nothing is taken
    taken, backlog = [], []
    for arrival, cam, stamp, k in frames:
        if stall[0] <= arrival < stall[1]:
            backlog.append((cam, stamp, k))
        else:
            taken.append((arrival, cam, stamp, k))
    sync = FrameSynchronizer(["cam0", "cam1", "cam2"], cfg)
    groups = []
    for arrival, cam, stamp, k in taken:
        if arrival >= stall[1] and backlog:
            groups += sync.poll(now=stall[1])            # the timer runs first after a stall
            per_cam = {c: [b for b in backlog if b[0] == c] for c in sync.cameras}
            while any(per_cam.values()):                  # one message per camera in turn
                for c in sync.cameras:
                    if per_cam[c]:
                        cam_, stamp_, k_ = per_cam[c].pop(0)
                        groups += sync.push(cam_, stamp_, k_, now=stall[1])
            backlog = []
        groups += sync.push(cam, stamp, k, now=arrival)
    assert len(groups) >= 58 and all(g.complete for g in groups)
    assert sync.stats.incomplete == 0 and sync.stats.dropped == 0
    # the same stall with cam1 stopped before it: named, and the rig goes on without it
    sync = FrameSynchronizer(["cam0", "cam1", "cam2"], cfg)
    groups = _run(sync, [f for f in frames if not (f[1] == "cam1" and f[0] > 0.5)])
    assert sync.missing(now=3.0) == ("cam1",)
    assert [g.missing for g in groups if not g.complete][-1] == ("cam1",)


def test_late_frames_are_counted_and_never_grouped():
    sync = FrameSynchronizer(["a", "b"], SyncConfig(tolerance_s=0.005))
    assert sync.push("a", 1.000, "a1", now=1.01) == []
    [g] = sync.push("b", 1.002, "b1", now=1.01)
    assert g.stamp == pytest.approx(1.001)
    assert sync.push("a", 0.95, "old", now=1.02) == []
    assert sync.stats.late == 1


def test_bad_input_is_refused_with_the_camera_list():
    sync = FrameSynchronizer(["a", "b"])
    with pytest.raises(InputError, match=r"\['a', 'b'\]"):
        sync.push("c", 1.0, None, now=1.0)
    with pytest.raises(InputError, match="finite"):
        sync.push("a", float("nan"), None, now=1.0)
    with pytest.raises(ConfigError):
        FrameSynchronizer(["a", "a"])
    with pytest.raises(ConfigError, match="min_cameras"):
        FrameSynchronizer(["a"], SyncConfig(min_cameras=2))


def test_queue_is_bounded_when_a_camera_lags():
    sync = FrameSynchronizer(["a", "b"], SyncConfig(max_queue=5, camera_timeout_s=10.0))
    for k in range(20):
        sync.push("a", k * 0.05, k, now=k * 0.05)
    assert sync.stats.overflow == 15
    assert sync.stats.groups == 0
