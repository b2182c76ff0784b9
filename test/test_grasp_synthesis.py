"""Grasp synthesis (dissertation III.4): the energy terms on known poses, the feasibility filter,
the swarm, Laplacian editing, and synthesised grasps of objects the database never saw."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hand_capture.model.joints import N_DOF
from hand_control.contact import ContactSet, dynamic_feasibility
from hand_control.errors import InputError
from hand_control.grasp.objects import make_object
from hand_control.grasp.pso import PSOConfig, pso
from hand_control.grasp.synthesis import (
    GraspControl,
    SynthesisConfig,
    laplacian_edit,
    model_contacts,
    synthesize,
)
from hand_control.grasp.terms import (
    EnergyWeights,
    HandGeometry,
    collision_term,
    contact_distance_term,
    grasp_quality_terms,
)


@pytest.fixture(scope="module")
def cube():
    return make_object("box", (0.025, 0.025, 0.025), mass=0.2, friction=0.6)


@pytest.fixture(scope="module")
def geometry():
    return HandGeometry()


@pytest.fixture(scope="module")
def models():
    from hand_control.grasp import load_grasp_models

    return load_grasp_models()


def _hand_points(geo: HandGeometry, q: np.ndarray) -> np.ndarray:
    rot, pos = geo.frames(q)
    return HandGeometry.points(rot, pos, geo.bones, geo.local)


def test_collision_term_counts_penetrating_frames(cube, geometry) -> None:
    far = np.zeros(N_DOF)
    far[2] = 0.3  # the wrist 30 cm above the cube
    inside = np.zeros(N_DOF)
    inside[0] = -0.04  # the palm through the cube
    frames = np.stack([far, far, inside, inside])[None]  # (1, 4, 27)
    pts = _hand_points(geometry, frames)
    e = collision_term(cube.sdf, pts, geometry.radii, floor_z=None, penalty=10.0)
    assert e[0] == pytest.approx(5.0)  # eq. (III.6): d = 10 in half of the frames
    assert collision_term(cube.sdf, pts[:, :2], geometry.radii, None)[0] == 0.0
    # the support plane counts too: the far pose is below a floor at z = 0.5
    assert collision_term(cube.sdf, pts[:, :2], geometry.radii, 0.5)[0] == pytest.approx(10.0)


def test_contact_distance_is_the_distance_to_the_surface_in_mm() -> None:
    ball = make_object("sphere", (0.03,))
    d = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]])
    on = 0.03 * d
    out = 0.035 * d  # 5 mm outside each
    e = contact_distance_term(ball.sdf, np.stack([on, out]))
    assert e[0] < 1.5 and e[1] == pytest.approx(15.0, abs=1.5)


def test_grasp_quality_prefers_opposite_faces_to_adjacent_ones(cube) -> None:
    thumb = np.array([True, False])
    opposite = np.array([[-0.025, 0.0, 0.0], [0.025, 0.0, 0.0]])
    adjacent = np.array([[-0.025, 0.0, 0.0], [0.0, 0.025, 0.0]])
    eg1, eg2 = grasp_quality_terms(cube.sdf, np.stack([opposite, adjacent]), thumb, mu=0.6)
    assert eg2[0] < 0.05  # the line between the contacts lies in both friction cones
    assert eg2[1] > 2 * (math.pi / 4 - math.atan(0.6)) - 0.1  # 45 deg off each normal
    assert eg1[0] < 1.0 < eg1[1]  # centroid on the centre of mass vs 18 mm away


def test_feasibility_rejects_two_adjacent_faces_of_a_cube(cube) -> None:
    """Eq. (III.10)-(III.16) on the contacts the synthesis would hand it: surface points and
    inward normals read from the field."""
    from hand_control.grasp.synthesis import contact_patches

    def contacts(points: np.ndarray, patch: float = 0.0) -> ContactSet:
        surf, n_out, _ = cube.sdf.closest(points)
        return ContactSet(*contact_patches(surf, -n_out, patch), 0.6) if patch else \
            ContactSet(surf, -n_out, 0.6)

    adjacent = np.array([[-0.026, 0.0, 0.0], [0.0, 0.026, 0.0]])
    opposite = np.array([[-0.026, 0.0, 0.0], [0.026, 0.005, 0.0], [0.026, -0.005, 0.0]])
    pinch = np.array([[-0.026, 0.01, 0.0], [0.026, 0.01, 0.0]])  # 1 cm beside the centre
    assert not dynamic_feasibility(contacts(adjacent), 0.2, np.zeros(3)).feasible
    assert not dynamic_feasibility(contacts(adjacent, 0.004), 0.2, np.zeros(3)).feasible
    assert dynamic_feasibility(contacts(opposite), 0.2, np.zeros(3)).feasible
    # a two-finger pinch off the centre of mass: point contacts cannot hold the torque about
    # the pinch axis, soft-finger patches (four points each, III.4.1.3) can
    assert not dynamic_feasibility(contacts(pinch), 0.2, np.zeros(3)).feasible
    assert dynamic_feasibility(contacts(pinch, 0.004), 0.2, np.zeros(3)).feasible


def test_pso_minimises_within_its_box() -> None:
    target = np.array([0.3, -0.7, 1.2])

    def f(x: np.ndarray) -> np.ndarray:
        return ((x - target) ** 2).sum(axis=1)

    rng = np.random.default_rng(1)
    res = pso(f, rng.uniform(-2, 2, (20, 3)), np.full(3, -2.0), np.array([2.0, 2.0, 1.0]),
              PSOConfig(particles=20, iterations=60), rng)
    assert np.allclose(res.best_x, [0.3, -0.7, 1.0], atol=1e-2)  # z clipped to the box
    assert res.evaluations == 20 * 61
    with pytest.raises(InputError):
        pso(f, np.zeros((3, 2)), np.zeros(3), np.ones(3))


def test_laplacian_editing_meets_the_new_ends_and_keeps_the_shape() -> None:
    t = np.linspace(0, 1, 30)[:, None]
    example = np.c_[np.sin(3 * t), t ** 2]
    start, end = np.array([0.5, 0.1]), np.array([0.2, 1.4])
    out = laplacian_edit(example, start, end)
    assert np.allclose(out[0], start, atol=0.01) and np.allclose(out[-1], end, atol=0.01)
    lap = lambda m: m[:-2] + m[2:] - 2 * m[1:-1]
    assert np.abs(lap(out) - lap(example)).max() < 0.01
    same = laplacian_edit(example, example[0], example[-1])
    assert np.allclose(same, example, atol=1e-6)


def test_synthesis_grasps_a_novel_object_without_penetrating_it(models, geometry) -> None:
    bottle = make_object("bottle", mass=0.2, friction=0.75)
    cfg = SynthesisConfig(seed=3)
    res = synthesize(bottle, models, GraspControl(grip_mode="thumb_index_middle"), cfg,
                     geometry=geometry)
    assert res.feasible and res.status == "optimal"
    assert res.motion.shape[1] == N_DOF and np.isfinite(res.motion).all()
    # the refinement put every contact on the surface (aimed grasp_depth inside)
    assert np.allclose(res.residual, cfg.grasp_depth, atol=1.5e-3)
    # no hand capsule crosses the bottle while closing, except the contacts' squeeze
    r = np.array([[math.cos(res.yaw), -math.sin(res.yaw), 0], [math.sin(res.yaw),
                  math.cos(res.yaw), 0], [0, 0, 1]])
    pts = _hand_points(geometry, res.motion[:-1]) @ r.T
    depth = geometry.radii - bottle.sdf(pts)
    from hand_capture.model.skeleton import BONE_NAMES

    fingers = {n.split("_")[0] for n in res.contact_bones}
    contact = np.array([BONE_NAMES[b].split("_")[0] in fingers for b in geometry.bones])
    assert depth[:, ~contact].max() < 0.003  # the field's 2 mm tolerance and its voxel
    assert depth.max() < 0.006  # contact fingers: at most the grasping pose's squeeze
    # the same seed gives the same grasp
    again = synthesize(bottle, models, GraspControl(grip_mode="thumb_index_middle"), cfg,
                       geometry=geometry)
    assert np.allclose(again.motion, res.motion)


def test_contact_targets_steer_the_grasp(models, geometry) -> None:
    """The motion control term (E_c): a contact point asked for a side of the box."""
    box = make_object("box", (0.03, 0.022, 0.03), mass=0.2)
    got = {}
    for side in (1.0, -1.0):
        ctl = GraspControl(grip_mode="thumb_index", approach_yaw=0.0,
                           contact_targets={"thumb": (0.0, side * 0.022, 0.0)})
        res = synthesize(box, models, ctl, SynthesisConfig(seed=0, yaw_range=math.pi),
                         geometry=geometry)
        i = [b.startswith("thumb") for b in res.contact_bones].index(True)
        got[side] = res.contact_points[i]
    assert got[1.0][1] > 0.01 and got[-1.0][1] < -0.01


def test_performer_motion_steers_the_synthesis(models, geometry) -> None:
    """III.6: with the performer's (tracked) closing motion as E_c, the synthesis follows it."""
    model = models["thumb_index_middle"]
    ball = make_object("sphere", (0.03,), mass=0.1)
    target = model.decode(model.sample(1, np.random.default_rng(5))[0])
    res = synthesize(ball, models, GraspControl(grip_mode="thumb_index_middle",
                                                performer=target), SynthesisConfig(seed=1),
                     geometry=geometry)
    free = synthesize(ball, models, GraspControl(grip_mode="thumb_index_middle"),
                      SynthesisConfig(seed=1), geometry=geometry)
    def err(r):  # wrist distance to the performer at the grasp [m], body frame
        c, s = math.cos(r.yaw), math.sin(r.yaw)
        w = np.array([[c, -s], [s, c]]) @ r.motion[-1, 0:2]
        return float(np.linalg.norm(w - target[-1, 0:2]))
    assert err(res) < err(free)
    assert err(res) < 0.02


def test_bad_control_input_is_refused(models) -> None:
    box = make_object("box")
    with pytest.raises(InputError, match="unknown grip mode"):
        synthesize(box, models, GraspControl(grip_mode="no_such_grip"))
    with pytest.raises(InputError, match="does not use"):
        synthesize(box, models, GraspControl(grip_mode="thumb_index",
                                             contact_targets={"little": (0, 0, 0)}))
    with pytest.raises(InputError, match="performer"):
        synthesize(box, models, GraspControl(grip_mode="thumb_index",
                                             performer=np.full((5, 27), np.nan)))


def test_model_contacts_come_from_the_database(models) -> None:
    c = model_contacts(models["thumb_index"])
    assert {n.split("_")[0] for n in c.names} >= {"thumb", "index"}
    assert c.is_thumb.any() and (~c.is_thumb).any()


def test_ablation_weights() -> None:
    from hand_control.grasp.synthesis import with_weights

    w = EnergyWeights()
    assert with_weights(w, "no_collision").w_k == 0 and with_weights(w, "no_cone").w2 == 0
    assert with_weights(w, "no_polygon").w1 == 0 and with_weights(w, "full") == w
    with pytest.raises(InputError):
        with_weights(w, "no_prior")


def test_a_scenario_lifts_an_object_the_database_never_saw() -> None:
    """lift_bottle: the grasp from synthesis, executed by the composite controller."""
    from hand_control.sim.lockstep import LockstepRunner
    from hand_control.sim.scenario import load_scenario

    spec = load_scenario("lift_bottle")
    assert spec.grasp_source == "synthesis" and spec.object_shape == "bottle"
    runner = LockstepRunner(spec)
    assert runner.plan.source == "synthesis" and runner.plan.closing is not None
    assert runner.reference.initial_pose == pytest.approx(runner.plan.reaching[0])
    r = runner.run()
    assert r.success and r.object_lift_mm > 80.0


def test_ik_scenarios_on_a_shape_need_a_primitive_proxy() -> None:
    from hand_control.errors import ConfigError
    from hand_control.sim.lockstep import LockstepRunner
    from hand_control.sim.scenario import ScenarioSpec

    with pytest.raises(ConfigError, match="synthesis"):
        LockstepRunner(ScenarioSpec(object_shape="torus", grasp_source="ik"))


def test_teleop_grasps_a_stone_with_the_grasp_synthesised_from_the_operators_hand() -> None:
    """III.6 offline: the operator's performance was made for lift_box's box; the scene has a
    convex stone there instead. As closing begins, the grasp is synthesised for the stone from
    the operator's hand (wrist and approach), and the stone is lifted and carried."""
    from hand_control.grasp.synthesis import PerformerSynthesizer
    from hand_control.sim.lockstep import LockstepRunner, scenario_object
    from hand_control.sim.scenario import load_scenario
    from hand_control.teleop.clip import performance_for_scenario
    from hand_control.teleop.offline import run_teleop
    from hand_control.teleop.phases import Phase

    perf = performance_for_scenario("lift_box")
    idx = np.arange(0, len(perf.times), 2)  # a 30 fps camera
    spec = load_scenario("teleop_stone")
    runner = LockstepRunner(spec, control_every=4)
    syn = PerformerSynthesizer(scenario_object(spec), runner.obj.name)
    res = run_teleop(runner, perf.times[idx], perf.poses[idx], synthesizer=syn)
    assert syn.last is not None and syn.last.feasible
    order = [int(p) for i, p in enumerate(res.phases) if i == 0 or p != res.phases[i - 1]]
    assert order[:4] == [Phase.REACHING, Phase.CLOSING, Phase.MANIPULATION, Phase.RELEASING]
    assert res.max_lift_mm > 70.0 and res.carried_mm > 70.0


def test_grasp_command_writes_and_plays_a_grasp(tmp_path, capsys) -> None:
    """``hand-suite grasp OBJECT -o OUT --play``: the motion file, the lift in simulation."""
    from hand_control.cli import main

    out = tmp_path / "g.npz"
    assert main(["grasp", "convex:5", "--mass", "0.15", "-o", str(out), "--play"]) == 0
    data = np.load(out)
    assert data["closing"].shape[1] == N_DOF and len(data["reaching"]) > 0
    assert str(data["grip_mode"]) in (
        "thumb_index", "thumb_middle", "thumb_ring", "thumb_index_middle", "thumb_middle_ring",
        "thumb_index_middle_ring", "all_except_index", "all_fingers", "spherical", "power")
    assert bool(data["feasible"])
    assert "held 2 s at 10 cm" in capsys.readouterr().out
    # a bad object is a clear error (exit code 2), not a traceback
    assert main(["grasp", str(tmp_path / "missing.stl")]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_reaching_and_manipulation_paths_meet_their_ends() -> None:
    """III.4.2 / III.4.3: the database example nearest to the boundary, edited by III.17."""
    from hand_control.grasp import load_grasp_database
    from hand_control.grasp.synthesis import manipulation_path, reaching_motion

    records = load_grasp_database()
    closing = records[0].closing
    q0 = closing[0].copy()
    q0[0:3] += (-0.05, 0.0, 0.04)
    reach = reaching_motion(records, q0, closing, frames=25)
    assert reach.shape == (25, N_DOF)
    assert np.allclose(reach[0], q0, atol=2e-3) and np.allclose(reach[-1], closing[0], atol=2e-3)
    path = manipulation_path(records, np.zeros(3), np.array([0.0, 0.1, 0.12]), frames=40)
    assert path.shape == (40, 3)
    assert np.allclose(path[0], 0.0, atol=2e-3)
    assert np.allclose(path[-1], [0.0, 0.1, 0.12], atol=2e-3)
