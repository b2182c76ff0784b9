"""Grasp database (III.3) and closing-phase model (III.4.1.1): DTW, warps, PCA/GMM, files."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hand_capture.model.joints import N_DOF
from hand_control.errors import InputError
from hand_control.grasp import (
    GRIP_MODES,
    ClosingModel,
    GraspRecord,
    fit_closing_model,
    from_object_frame,
    load_grasp_database,
    load_grasp_models,
    to_object_frame,
)
from hand_control.grasp.closing import resample
from hand_control.grasp.dtw import dtw_path, register, warp_from_path
from hand_control.grasp.train import reconstruction_error


def _signal(u: np.ndarray) -> np.ndarray:
    """A smooth 3-D curve on [0, 1] with no flat stretch (DTW has one right answer)."""
    return np.stack([np.sin(3.0 * u), np.cos(5.0 * u) * u, u ** 2 + 0.3 * np.sin(7.0 * u)],
                    axis=1)


def test_dtw_recovers_a_known_warp() -> None:
    t_ref, n = 60, 85
    ref = _signal(np.linspace(0.0, 1.0, t_ref))
    # the segment plays the same curve on a slow-then-fast timeline phi (monotonic)
    v = np.linspace(0.0, 1.0, n)
    phi = v ** 1.6
    seg = _signal(phi)
    w, warped = register(ref, seg)
    # truth: reference frame t shows the curve at u = t / (T-1); the segment shows it at
    # frame j with phi(j / (n-1)) = u
    u = np.linspace(0.0, 1.0, t_ref)
    truth = (n - 1) * u ** (1.0 / 1.6)
    assert np.abs(w - truth).mean() < 1.0  # frames
    assert np.abs(warped - ref).max() < 0.05
    path = dtw_path(ref, seg)
    assert tuple(path[0]) == (0, 0) and tuple(path[-1]) == (t_ref - 1, n - 1)
    assert (np.diff(path, axis=0) >= 0).all()


def test_registered_warps_are_strictly_monotonic_even_for_flat_stretches() -> None:
    ref = _signal(np.linspace(0, 1, 40))
    seg = np.vstack([np.repeat(ref[:1], 20, axis=0), ref])  # a long pause, then the motion
    w = warp_from_path(dtw_path(ref, seg), 40, seg.shape[0])
    assert w[0] == 0.0 and math.isclose(w[-1], seg.shape[0] - 1)
    assert (np.diff(w) > 0).all()


def _closing_set(n: int, seed: int) -> list[np.ndarray]:
    """Closing motions like the generator's: a pre-grasp -> grasp blend whose fingers close
    on their own random timelines, of random lengths, the grasp varying by demonstration."""
    rng = np.random.default_rng(seed)
    base0 = np.r_[-0.08, 0.0, 0.05, 0.0, 0.0, 0.0, np.full(N_DOF - 6, 0.1)]
    base1 = base0.copy()
    base1[6:] = 0.9
    # the poses vary along a few directions (object size, wrist placement, thumb), as grasps
    # of one grip mode do
    scale = np.r_[np.full(3, 0.1), np.ones(N_DOF - 3)]
    modes0 = rng.normal(0, 0.05, (3, N_DOF)) * scale
    modes1 = rng.normal(0, 0.1, (3, N_DOF)) * scale
    group = np.r_[np.zeros(6, dtype=int), np.ones(5, dtype=int), np.repeat(np.arange(2, 6), 4)]
    out = []
    for _ in range(n):
        z = rng.standard_normal(3)
        q0, q1 = base0 + z @ modes0, base1 + z @ modes1
        length = int(rng.integers(30, 60))
        u = np.linspace(0, 1, length)[:, None]
        k = rng.uniform(-2, 2)
        g = np.expm1(k * u) / math.expm1(k)
        lag = rng.uniform(0, 0.2, 6)[group]  # each finger (and the wrist) on its own time
        x = np.clip((g - lag) / (1 - lag), 0, 1) ** rng.uniform(0.7, 1.5, 6)[group]
        s = x * x * (3 - 2 * x)
        out.append(q0 + s * (q1 - q0))
    return out


@pytest.fixture(scope="module")
def model() -> tuple[ClosingModel, list[np.ndarray]]:
    segs = _closing_set(14, seed=1)
    return fit_closing_model("thumb_index", segs, fps=100.0), segs


def test_time_warps_of_the_model_stay_monotonic(model) -> None:
    m, _ = model
    rng = np.random.default_rng(0)
    params = m.mean() + 4.0 * rng.standard_normal((200, m.n_params))  # far outside the data
    h = m.warp(params)
    assert (np.diff(h, axis=1) > 0).all()
    assert (h[:, 0] == 0).all()
    d = m.decode(params[:5])
    assert d.shape == (5, m.n_frames, N_DOF) and np.isfinite(d).all()
    # absurd parameters (a swarm can fly anywhere): still a finite motion, increasing warp
    wild = np.array([np.full(m.n_params, 60.0), np.full(m.n_params, -60.0)])
    assert np.isfinite(m.decode(wild)).all()
    assert (np.diff(m.warp(wild), axis=1) > 0).all()


def test_model_reproduces_its_training_motions(model) -> None:
    m, segs = model
    errs = [reconstruction_error(m, s) for s in segs]
    for e in errs:
        assert e["finger_mean_rad"] < 0.03, e
        assert e["wrist_mean_m"] < 0.003, e
        assert e["duration_rel"] < 0.08, e
    assert np.mean([e["finger_mean_rad"] for e in errs]) < 0.015
    assert np.mean([e["duration_rel"] for e in errs]) < 0.02
    # the decoded motion ends in the grasping pose of the demonstration
    p = m.encode(segs[3])
    assert np.abs(m.final_pose(p) - segs[3][-1])[6:].max() < 0.05
    np.testing.assert_allclose(m.final_pose(p), m.decode(p)[-1], atol=1e-12)


def test_prior_prefers_the_data_and_samples_from_it(model) -> None:
    m, segs = model
    train = m.train_params
    assert train.shape == (len(segs), m.n_params)
    far = m.mean() + 6.0 * np.ones(m.n_params)
    assert m.neg_log_prior(far) > m.neg_log_prior(train).max()
    s = m.sample(4000, np.random.default_rng(2))
    assert s.shape == (4000, m.n_params)
    np.testing.assert_allclose(s.mean(axis=0), m.mean(), atol=0.15)
    lo, hi = m.bounds(3.0)
    assert ((train >= lo) & (train <= hi)).all()


def test_model_rejects_bad_parameters_and_round_trips_through_a_file(model, tmp_path) -> None:
    m, _ = model
    with pytest.raises(InputError, match="params must be"):
        m.decode(np.zeros(m.n_params + 1))
    with pytest.raises(InputError, match="NaN"):
        m.neg_log_prior(np.full(m.n_params, np.nan))
    with pytest.raises(InputError, match="motion"):
        m.encode(np.zeros((10, 5)))
    m.save(tmp_path / "m.npz")
    m2 = ClosingModel.load(tmp_path / "m.npz")
    p = m.sample(3, 0)
    np.testing.assert_allclose(m2.decode(p), m.decode(p), atol=1e-6)
    np.testing.assert_allclose(m2.neg_log_prior(p), m.neg_log_prior(p))
    with pytest.raises(InputError):
        ClosingModel.load(tmp_path / "missing.npz")


def test_object_frame_round_trip_and_heading() -> None:
    rng = np.random.default_rng(0)
    m = rng.normal(0, 0.3, (20, N_DOF))
    origin, yaw = np.array([0.12, -0.02, 0.03]), 0.7
    back = from_object_frame(to_object_frame(m, origin, yaw), origin, yaw)
    np.testing.assert_allclose(back, m, atol=1e-9)
    # a hand at the object's -x side after the turn: the frame's x points at the object
    p = np.zeros(N_DOF)
    p[0:3] = origin - 0.1 * np.array([math.cos(yaw), math.sin(yaw), 0.0])
    q = to_object_frame(p, origin, yaw)
    np.testing.assert_allclose(q[0:3], [-0.1, 0.0, 0.0], atol=1e-12)


def test_record_validation() -> None:
    with pytest.raises(InputError, match="grip mode"):
        GraspRecord("fist", "box", (0.02,) * 3, 0.1, np.zeros((5, N_DOF)), (1, 3), ())
    with pytest.raises(InputError, match="phases"):
        GraspRecord("thumb_index", "box", (0.02,) * 3, 0.1, np.zeros((5, N_DOF)), (3, 9), ())
    with pytest.raises(InputError, match="motion"):
        GraspRecord("thumb_index", "box", (0.02,) * 3, 0.1, np.full((5, N_DOF), np.nan),
                    (1, 3), ())


# ---- the shipped database and models ----------------------------------------------------
def _surface_distance(kind: str, size: tuple[float, ...], p: np.ndarray) -> float:
    if kind == "ball":
        return abs(float(np.linalg.norm(p)) - size[0])
    if kind == "cylinder":
        return abs(float(np.hypot(p[0], p[1])) - size[0])
    # a box turned about z in the object frame: between the half side and the half diagonal
    r = float(np.hypot(p[0], p[1]))
    lo, hi = min(size[0], size[1]), math.hypot(size[0], size[1])
    return max(lo - r, r - hi, abs(p[2]) - size[2], 0.0)


def test_shipped_database_is_in_the_object_frame_and_was_lifted() -> None:
    import mujoco

    from hand_control.sim.lockstep import build_world
    from hand_control.sim.scenario import ScenarioSpec

    records = load_grasp_database()
    modes = {r.grip_mode for r in records}
    assert len(modes) >= 8, sorted(modes)
    world, _, _ = build_world(ScenarioSpec())
    mdl = world.model
    data = mujoco.MjData(mdl)
    site = mujoco.mj_name2id(mdl, mujoco.mjtObj.mjOBJ_SITE, "palm_center")
    for r in records:
        assert r.lift_mm >= 80.0, r.lift_mm  # the simulation check: lifted (10 cm asked)
        # the palm centre at the grasping pose lies on the object frame's -x axis
        data.qpos[:N_DOF] = r.grasp_pose
        mujoco.mj_kinematics(mdl, data)
        palm = data.site_xpos[site]
        assert palm[0] < 0.0 and abs(palm[1]) < 1e-3, palm
        # the contacts lie on the object's surface around the origin (its centre of mass)
        assert r.contacts and any(b.startswith("thumb") for b, _ in r.contacts)
        for _, p in r.contacts:
            assert _surface_distance(r.object_kind, r.object_size, np.array(p)) < 0.004
        # the phases split the motion into reaching, closing and manipulation
        assert 0 < r.phases[0] < r.phases[1] < r.motion.shape[0]


def test_shipped_models_reproduce_their_database() -> None:
    models = load_grasp_models()
    records = load_grasp_database()
    assert set(models) <= set(GRIP_MODES) and len(models) >= 8
    for g, m in models.items():
        rs = [r for r in records if r.grip_mode == g]
        assert len(rs) >= 3
        assert m.contacts, g
        for r in rs:
            e = reconstruction_error(m, r.closing)
            assert e["finger_mean_rad"] < 0.05, (g, e)
        closing = m.decode(m.mean())
        assert closing.shape == (m.n_frames, N_DOF)
        # the mean closing motion closes: the contacting fingers flex more at the end
        assert closing[-1, 6:].sum() > closing[0, 6:].sum()
        np.testing.assert_allclose(resample(closing, 5)[-1], m.final_pose(m.mean()),
                                   atol=1e-9)


def test_train_grasps_quick_is_reproducible(tmp_path) -> None:
    from hand_control.grasp.train import main

    args = ["--quick", "--modes", "thumb_index", "--demos", "3", "--attempts", "6",
            "--seed", "5"]
    assert main(args + ["--out", str(tmp_path / "a")]) == 0
    assert main(args + ["--out", str(tmp_path / "b")]) == 0
    da, db = (load_grasp_database(tmp_path / x) for x in "ab")
    assert len(da) == len(db) == 3
    for ra, rb in zip(da, db, strict=True):
        np.testing.assert_array_equal(ra.motion, rb.motion)
        assert ra.contacts == rb.contacts and ra.phases == rb.phases
    for f in ("database.npz", "closing_thumb_index.npz"):  # the very same files
        assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes()
    ma, mb = (load_grasp_models(tmp_path / x)["thumb_index"] for x in "ab")
    np.testing.assert_array_equal(ma.p_basis, mb.p_basis)
    np.testing.assert_array_equal(ma.gmm_means, mb.gmm_means)
    # a different seed gives a different database
    assert main(args[:-1] + ["6", "--out", str(tmp_path / "c")]) == 0
    dc = load_grasp_database(tmp_path / "c")
    assert not np.array_equal(dc[0].motion, da[0].motion)


def test_generator_keeps_only_demonstrations_the_simulation_lifted(monkeypatch) -> None:
    from hand_control.grasp import generate

    real = generate._object_for
    # the same draws, but a 2 kg object with the friction of ice: no fingertip grip lifts it
    monkeypatch.setattr(generate, "_object_for",
                        lambda mode, rng: real(mode, rng)[:2] + (2.0, 0.05))
    rng_args = (0, GRIP_MODES.index("thumb_index_middle"), 0)
    why: list[str] = []
    assert generate.demonstrate("thumb_index_middle", np.random.default_rng(rng_args),
                                why=why) is None
    assert why and why[0].startswith("not lifted"), why
    monkeypatch.setattr(generate, "_object_for", real)
    rec = generate.demonstrate("thumb_index_middle", np.random.default_rng(rng_args))
    assert rec is not None and rec.lift_mm > 80.0
    assert {b.split("_")[0] for b, _ in rec.contacts} >= {"thumb"}
