"""MJCF export: MuJoCo reproduces the numpy FK, scenes simulate cleanly, PD gains."""

from __future__ import annotations

import numpy as np
import pytest

from hand_capture.errors import ConfigError, InputError
from hand_capture.model import (
    BONE_NAMES,
    FINGERS,
    JOINT_LIMITS,
    JOINT_NAMES,
    HandModel,
    sample_shape,
)
from hand_capture.model.mjcf import (
    DEFAULT_SCENES,
    FINGER_ARMATURE,
    GAIN_TABLE,
    ObjectSpec,
    build_hand,
    build_scene,
    dof_gains,
    export_mjcf,
    finger_torque_limits,
    gain_row,
    home_pose,
    root_rot_armature,
)

mujoco = pytest.importorskip("mujoco")


def _load(xml: str):
    m = mujoco.MjModel.from_xml_string(xml)
    return m, mujoco.MjData(m)


def _ids(m, kind, names):
    return [mujoco.mj_name2id(m, kind, n) for n in names]


@pytest.mark.parametrize("side", ["right", "left"])
def test_mujoco_fk_matches_model(side: str) -> None:
    model = HandModel(sample_shape(21), side=side)
    m, d = _load(build_hand(hand=side, model=model))
    assert m.nq == m.nv == m.nu == 27
    assert [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, i) for i in range(27)] == list(
        JOINT_NAMES)
    assert [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, i) for i in range(27)] == list(
        JOINT_NAMES)
    np.testing.assert_allclose(m.jnt_range[6:], JOINT_LIMITS[6:], atol=1e-9)
    assert not m.jnt_limited[:6].any() and m.jnt_limited[6:].all()
    bodies = _ids(m, mujoco.mjtObj.mjOBJ_BODY, BONE_NAMES)
    sites = _ids(m, mujoco.mjtObj.mjOBJ_SITE, [f"{f}_tip" for f in FINGERS])
    assert min(bodies) > 0 and min(sites) >= 0
    rng = np.random.default_rng(0)
    lo = np.r_[-0.5, -0.5, -0.5, -np.pi, -1.5, -np.pi, JOINT_LIMITS[6:, 0]]
    hi = np.r_[0.5, 0.5, 0.5, np.pi, 1.5, np.pi, JOINT_LIMITS[6:, 1]]
    for q in rng.uniform(lo, hi, size=(25, 27)):
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        fk = model.forward(q)
        np.testing.assert_allclose(d.xpos[bodies], fk.joint_frames[:, :3, 3], atol=1e-6, rtol=0)
        np.testing.assert_allclose(d.xmat[bodies].reshape(-1, 3, 3), fk.joint_frames[:, :3, :3],
                                   atol=1e-6, rtol=0)
        np.testing.assert_allclose(d.site_xpos[sites], fk.fingertips, atol=1e-6, rtol=0)
        # collision capsules sit where the model puts them
        seg = model.capsule_segments(q)
        for c, s in zip(model.capsules, seg, strict=True):
            g = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, c.name)
            np.testing.assert_allclose(d.geom_xpos[g], s.mean(axis=0), atol=1e-6, rtol=0)
            assert m.geom_size[g, 0] == pytest.approx(c.radius)


def test_hand_mass_and_home_keyframe() -> None:
    m, d = _load(build_hand())
    palm = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "palm")
    assert 0.35 < m.body_subtreemass[palm] < 0.6  # ~0.6 % of body mass (de Leva 1996)
    assert np.all(m.body_mass[1:] > 0) and np.all(m.body_inertia[1:] > 0)
    key = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_KEY, "home")
    np.testing.assert_allclose(m.key_qpos[key], home_pose())
    # qpos0 (reset) holds the wrist at the slides' ref position
    mujoco.mj_kinematics(m, d)
    np.testing.assert_allclose(d.xpos[palm], home_pose()[:3])


def _step_random(xml: str, seconds: float, seed: int) -> tuple[object, object]:
    m, d = _load(xml)
    mujoco.mj_resetDataKeyframe(m, d, 0)
    rng = np.random.default_rng(seed)
    # targets within each servo's control range, or its joint's range (finger servos)
    lim = m.actuator_ctrllimited.astype(bool)
    jnt = m.actuator_trnid[:, 0]
    lo = np.where(lim, m.actuator_ctrlrange[:, 0], m.jnt_range[jnt, 0])
    hi = np.where(lim, m.actuator_ctrlrange[:, 1], m.jnt_range[jnt, 1])
    for i in range(int(round(seconds / m.opt.timestep))):
        if i % 50 == 0:
            d.ctrl[:] = rng.uniform(lo, hi)
        mujoco.mj_step(m, d)
    return m, d


@pytest.mark.parametrize("objects", list(DEFAULT_SCENES.values()),
                         ids=list(DEFAULT_SCENES.keys()))
def test_scenes_step_without_warnings(objects: tuple[str, ...]) -> None:
    xml = build_scene(objects, shape=sample_shape(2))
    m, d = _step_random(xml, 1.0, seed=len(objects))
    assert m.opt.timestep == pytest.approx(0.001)
    assert all(int(w.number) == 0 for w in d.warning), [int(w.number) for w in d.warning]
    assert np.all(np.isfinite(d.qpos)) and np.all(np.isfinite(d.qvel))
    assert m.nq == 27 + 7 * len(objects)


def test_left_scene_and_objects_rest_on_the_table() -> None:
    objs = [ObjectSpec("box", name="cube", mass=0.2, friction=1.2), "ball", "stick", "cup"]
    m, d = _load(build_scene(objs, hand="left"))
    mujoco.mj_resetDataKeyframe(m, d, 0)
    d.ctrl[:6] = home_pose()[:6]
    for _ in range(500):
        mujoco.mj_step(m, d)
    assert all(int(w.number) == 0 for w in d.warning)
    for name in ("cube", "ball", "stick", "cup"):
        b = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, name)
        assert np.linalg.norm(d.cvel[b]) < 0.05, name  # at rest
        assert d.xpos[b, 2] > 0.0
    cube = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "cube")
    assert m.body_subtreemass[cube] == pytest.approx(0.2)
    g = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "cube_0")
    assert m.geom_friction[g, 0] == pytest.approx(1.2)
    cup = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "cup")
    assert m.body_subtreemass[cup] == pytest.approx(0.3)


def test_position_servos_with_table_gains_track_and_are_stable() -> None:
    """Every DoF is a MuJoCo position servo with the gains of Table 1 (eq. 8): ctrl = target."""
    m, d = _load(build_scene(["box"]))
    mujoco.mj_resetDataKeyframe(m, d, 0)
    rng = np.random.default_rng(3)
    target = home_pose()
    for i in range(1500):
        if i % 300 == 0:
            target[6:] = rng.uniform(JOINT_LIMITS[6:, 0], JOINT_LIMITS[6:, 1])
        d.ctrl[:] = target
        mujoco.mj_step(m, d)
    assert all(int(w.number) == 0 for w in d.warning)
    assert np.abs(d.qvel[6:27]).max() < 5.0  # settled, no oscillation
    err = np.abs(d.qpos[6:27] - target[6:])
    assert np.median(err) < 0.05


def test_servo_gains_and_torque_limits_are_written_into_the_mjcf() -> None:
    kp, kd = dof_gains()
    m, _ = _load(build_hand())
    assert m.nu == 27 and (m.actuator_biastype == mujoco.mjtBias.mjBIAS_AFFINE).all()
    np.testing.assert_allclose(m.actuator_gainprm[:, 0], kp)
    np.testing.assert_allclose(m.actuator_biasprm[:, 1], -kp)
    np.testing.assert_allclose(m.actuator_biasprm[:, 2], -kd)
    for name, k in (("root_tx", 0), ("root_rz", 5), ("thumb_tm_abd", 6), ("index_dip_flex", 14),
                    ("little_mcp_flex", 23)):
        assert (kp[k], kd[k]) == GAIN_TABLE[gain_row(name)]
    lim = finger_torque_limits()
    np.testing.assert_allclose(m.actuator_forcerange[6:, 1], lim[6:])
    # a fingertip force (40 N, thumb 80 N) times the joint-to-tip distance: MCP > PIP > DIP
    i = {n: JOINT_NAMES.index(n) for n in ("index_mcp_flex", "index_pip_flex",
                                           "index_dip_flex", "thumb_tm_flex")}
    assert lim[i["index_mcp_flex"]] > lim[i["index_pip_flex"]] > lim[i["index_dip_flex"]]
    assert 2.0 < lim[i["index_mcp_flex"]] < 6.0 and 0.4 < lim[i["index_dip_flex"]] < 1.5
    assert lim[i["thumb_tm_flex"]] > lim[i["index_mcp_flex"]]
    # other gains go into the file, and bad ones are refused
    m2, _ = _load(build_hand(servo_kp=2 * kp, servo_kd=kd))
    np.testing.assert_allclose(m2.actuator_gainprm[:, 0], 2 * kp)
    with pytest.raises(ConfigError):
        build_hand(servo_kp=kp[:26])
    with pytest.raises(ConfigError):
        build_scene(servo_kp=-kp)
    with pytest.raises(ConfigError):
        gain_row("wrist")


def test_armature_is_small_against_the_links() -> None:
    """The finger armature is below the inertia of every MCP / TM link about its axis (the
    former 1e-3 was 10x-5000x the links)."""
    m, d = _load(build_hand())
    mujoco.mj_resetDataKeyframe(m, d, 0)
    mujoco.mj_forward(m, d)
    full = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, d, full)
    link = np.diag(full)[6:27] - m.dof_armature[6:27]  # the links' inertia about each axis
    assert np.allclose(m.dof_armature[6:27], FINGER_ARMATURE)
    assert 1e-7 < link.min() < 1e-6 and link.max() < 1e-3
    root = [JOINT_NAMES.index(n) - 6 for n in JOINT_NAMES[6:]
            if "_mcp_" in n or "_tm_" in n]
    assert (FINGER_ARMATURE <= link[root]).all()
    assert FINGER_ARMATURE <= 1e-3 / 50


@pytest.mark.parametrize("kd", [None, 200.0])
def test_a_force_clamped_wrist_servo_saturates_without_chatter(kd: float | None) -> None:
    """A wrist target 0.5 rad away asks 300 N m of the 20 N m wrist servos. MuJoCo integrates
    a clamped actuator's damping explicitly; on the hand's own inertia (~1e-3 kg m^2) the Table
    1 damping (50 N m s/rad) then flipped the torque from one limit to the other 40-240 times
    in this step response (a moving wrist target, replayed from a teleop run, was lost by
    67 deg). With the armature sized from the damping (also for a larger kd) the servo pushes
    one way, at its limit, and arrives."""
    kp0, kd0 = dof_gains()
    kd_all = kd0.copy()
    if kd is not None:
        kd_all[3:6] = kd
    m, d = _load(build_scene(("box",), servo_kd=kd_all))
    np.testing.assert_allclose(m.dof_armature[3:6], root_rot_armature(kd_all[3:6]))
    assert (kd_all[3:6] * m.opt.timestep <= m.dof_armature[3:6]).all()
    mujoco.mj_resetDataKeyframe(m, d, 0)
    target = d.ctrl.copy()
    target[3:6] += (0.5, -0.3, 0.5)
    d.ctrl[:] = target
    force = []
    for _ in range(1500):
        mujoco.mj_step(m, d)
        force.append(d.actuator_force[3:6].copy())
    f = np.array(force)
    lim = m.actuator_forcerange[3:6, 1]
    assert np.isclose(np.abs(f[:5]), lim).all()  # the step clamps all three at first
    flips = ((np.abs(f[1:]) > 0.9 * lim) & (np.abs(f[:-1]) > 0.9 * lim)
             & (np.sign(f[1:]) != np.sign(f[:-1]))).sum(axis=0)
    assert (flips == 0).all(), flips  # never from one limit to the other in a step
    assert np.degrees(np.abs(d.qpos[3:6] - target[3:6])).max() < 2.0
    assert all(int(w.number) == 0 for w in d.warning)


def test_object_spec_validation() -> None:
    with pytest.raises(InputError):
        ObjectSpec("teapot")
    with pytest.raises(InputError):
        ObjectSpec("box", size=(0.1, 0.1))
    with pytest.raises(InputError):
        ObjectSpec("ball", mass=-1.0)
    with pytest.raises(InputError):
        ObjectSpec("cup", size=(0.04, 0.05, 0.05))
    with pytest.raises(InputError):
        build_scene(["box", "box"])
    with pytest.raises(InputError):
        build_scene([3])  # type: ignore[list-item]
    with pytest.raises(InputError):
        build_scene(hand="middle")


def test_export_writes_loadable_files(tmp_path) -> None:
    out = export_mjcf(tmp_path, shape=sample_shape(4), hand="right")
    assert out.hand.name == "hand.xml" and out.hand.exists()
    assert set(out.scenes) == set(DEFAULT_SCENES)
    for p in [out.hand, *out.scenes.values()]:
        m = mujoco.MjModel.from_xml_path(str(p))
        assert m.nu == 27
