"""Rendered frames of the simulated grasp, from a recorded bag (MuJoCo offscreen, no GPU).

The scenario's world is rebuilt (the same MJCF the sim node stepped) and put, at a few instants,
into the recorded state: the hand joints from ``sim/joint_states`` and the object from
``sim/object_pose``; :func:`mujoco.mj_forward` then places every body and MuJoCo's offscreen
renderer (OSMesa where there is no display, ``MUJOCO_GL=osmesa``) draws it.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import numpy as np

from hand_control.report.series import BagData

__all__ = ["sim_frame_renderer"]


def _instants(data: BagData, n: int) -> list[int]:
    """Indices into sim/joint_states: the grasp phase changes when recorded, else evenly."""
    js = data.topics["sim/joint_states"]
    t_js = np.asarray(js.t_ns)
    picks: list[int] = []
    ph = data.topics.get("control/grasp_phase")
    if ph is not None and ph.msgs:
        last = None
        for t, m in zip(ph.t_ns, ph.msgs, strict=True):
            if m.phase != last:
                picks.append(int(np.searchsorted(t_js, t)))
                last = m.phase
    even = np.linspace(0, len(t_js) - 1, n).astype(int).tolist()
    picks = sorted({min(max(i, 0), len(t_js) - 1) for i in picks + even})
    if len(picks) > n:  # keep the first and last, thin the middle evenly
        keep = np.linspace(0, len(picks) - 1, n).round().astype(int)
        picks = [picks[i] for i in keep]
    return picks


def sim_frame_renderer(scenario: str, n_frames: int = 6, width: int = 480, height: int = 360,
                       azimuth: float = 180.0, elevation: float = -15.0
                       ) -> Callable[[BagData, Path], list[Path]]:
    """A ``frames_fn`` for :func:`hand_control.report.build_report`.

    Args:
        scenario: the scenario the sim node ran (its world is rebuilt).
        n_frames: at most this many frames.
        width, height: image size [px].
        azimuth, elevation: the free camera around the object [deg].
    """

    def render(data: BagData, out: Path) -> list[Path]:
        if not data.has("sim/joint_states"):
            return []
        os.environ.setdefault("MUJOCO_GL", "osmesa")
        os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])
        import mujoco

        from hand_control.sim.lockstep import build_world
        from hand_control.sim.scenario import load_scenario

        world, obj, _ = build_world(load_scenario(scenario))
        m, d = world.model, world.data
        index = {n: i for i, n in enumerate(world.joint_names)}
        o = world.objects[obj.name]
        js = data.topics["sim/joint_states"]
        po = data.topics.get("sim/object_pose")
        t_po = np.asarray(po.t_ns) if po is not None and po.msgs else None
        cam = mujoco.MjvCamera()
        cam.lookat[:] = world.object_pose(obj.name).position + np.array([0.0, 0.05, 0.06])
        cam.distance, cam.azimuth, cam.elevation = 0.55, azimuth, elevation
        paths: list[Path] = []
        renderer = mujoco.Renderer(m, height, width)
        try:
            for k, i in enumerate(_instants(data, n_frames)):
                msg = js.msgs[i]
                for name, v in zip(msg.name, msg.position, strict=True):
                    j = index.get(name)
                    if j is not None:
                        d.qpos[world.qpos_adr[j]] = v
                if t_po is not None:
                    p = po.msgs[min(int(np.searchsorted(t_po, js.t_ns[i])), len(po.msgs) - 1)]
                    q = p.pose
                    d.qpos[o["qpos"]:o["qpos"] + 7] = (
                        q.position.x, q.position.y, q.position.z, q.orientation.w,
                        q.orientation.x, q.orientation.y, q.orientation.z)
                mujoco.mj_forward(m, d)
                renderer.update_scene(d, camera=cam)
                img = renderer.render()
                t = (js.t_ns[i] - js.t_ns[0]) * 1e-9
                path = out / f"sim_frame_{k}_{t:05.2f}s.png"
                _save_png(path, img)
                paths.append(path)
        finally:
            renderer.close()
        return paths

    return render


def _save_png(path: Path, rgb: np.ndarray) -> None:
    import cv2

    if not cv2.imwrite(str(path), np.ascontiguousarray(rgb[:, :, ::-1])):
        raise OSError(f"could not write {path}")
