"""Contact-force QP (dissertation eq. III.23, seed 000 eq. 10-11): fast path vs cvxpy reference,
friction cones, a closed-form gravity-compensation case, bad input and failure statuses."""

from __future__ import annotations

import dataclasses
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hand_capture.errors import ConfigError
from hand_control.bench.contact import random_problems
from hand_control.contact import (
    ContactForceQP,
    ContactQPConfig,
    ContactSet,
    ReferenceContactQP,
    contact_frames,
    pyramid_edges,
)
from hand_control.errors import InputError

G = 9.81

CONFIGS = {
    "dissertation": ContactQPConfig(),
    "torsion_bound": ContactQPConfig(torsion_bound=True, torsional_friction=0.01),
    "8_edges": ContactQPConfig(friction_edges=8),
    "seed000": ContactQPConfig(method="seed000"),
}


def cone_violation(contacts: ContactSet, forces: np.ndarray) -> float:
    """max_k |f_t| - mu f_n (<= 0 inside the Coulomb cone)."""
    fn = np.einsum("kj,kj->k", forces, contacts.normals)
    ft = np.linalg.norm(forces - fn[:, None] * contacts.normals, axis=1)
    return float(np.max(ft - contacts.mu * fn))


def objective_iii23(cfg, contacts, com, tf, tt, forces, torsion) -> float:
    r = contacts.points - com
    ef = forces.sum(0) - tf
    et = (np.cross(r, forces) + torsion[:, None] * contacts.normals).sum(0) - tt
    return (cfg.alpha1 * ef @ ef + cfg.alpha2 * et @ et
            + cfg.alpha3 * np.sum(forces**2) + cfg.alpha4 * torsion @ torsion)


@pytest.mark.parametrize("name", list(CONFIGS))
def test_fast_path_matches_cvxpy_on_random_problems(name):
    cfg = CONFIGS[name]
    fast, ref = ContactForceQP(cfg), ReferenceContactQP(cfg)
    for contacts, com, tf, tt in random_problems(seed=11, n=24):
        a, b = fast.solve(contacts, com, tf, tt), ref.solve(contacts, com, tf, tt)
        # a random contact set may be unable to push the object where the target says: both
        # solvers report it, with the same closest forces
        assert a.status == b.status and a.status in ("optimal", "unreachable"), \
            (a.status, b.status)
        np.testing.assert_allclose(a.forces, b.forces, rtol=0, atol=1e-6)
        np.testing.assert_allclose(a.torsion, b.torsion, rtol=0, atol=1e-6)
        assert a.objective <= b.objective + 1e-9
        if cfg.method == "dissertation":
            assert cone_violation(contacts, a.forces) <= 1e-9
            assert a.objective == pytest.approx(
                objective_iii23(cfg, contacts, com, tf, tt, a.forces, a.torsion), rel=1e-9)
        if cfg.torsion_bound:
            fn = np.einsum("kj,kj->k", a.forces, contacts.normals)
            assert np.all(np.abs(a.torsion) <= cfg.torsional_friction * fn + 1e-9)
        # the reported wrench error is the net wrench of the solution minus the target
        r = contacts.points - com
        net_t = (np.cross(r, a.forces) + a.torsion[:, None] * contacts.normals).sum(0)
        np.testing.assert_allclose(a.wrench_error, np.r_[a.forces.sum(0) - tf, net_t - tt],
                                   atol=1e-12)
        assert a.residual == pytest.approx(np.linalg.norm(a.wrench_error))
        assert a.solve_time_s > 0


def test_seed000_scales_the_simulator_forces():
    """eq. (10): f_aug,i = w_i f_c,i with w_i >= 0, so every force keeps its direction."""
    fast = ContactForceQP(CONFIGS["seed000"])
    for contacts, com, tf, tt in random_problems(seed=3, n=12):
        res = fast.solve(contacts, com, tf, tt)
        w = np.einsum("kj,kj->k", res.forces, contacts.forces) / np.einsum(
            "kj,kj->k", contacts.forces, contacts.forces)
        assert np.all(w >= 0)
        np.testing.assert_allclose(res.forces, w[:, None] * contacts.forces, atol=1e-12)


def pinch(mu: float = 0.5, half_width: float = 0.03) -> ContactSet:
    """Two fingertips on opposite faces of an object, at the height of its centre of mass."""
    return ContactSet([[-half_width, 0, 0], [half_width, 0, 0]], [[1, 0, 0], [-1, 0, 0]], mu)


def test_gravity_compensation_with_two_opposing_contacts():
    """Pure weight compensation: target force m g upwards, no torque.

    By symmetry each finger carries V upwards by friction with the smallest squeeze F = V/mu
    (the 4-edge pyramid has an edge in the vertical plane), so eq. (III.23) reduces to
    min a1 (2V - W)^2 + 2 a3 V^2 (1 + 1/mu^2), i.e. V = a1 W / (2 a1 + a3 (1 + 1/mu^2)).
    With the paper's a3 = 0.1 the regularisation leaves part of the weight uncompensated;
    with a small a3 the forces balance the weight.
    """
    mu, mass = 0.5, 0.2
    weight = mass * G
    contacts = pinch(mu)
    # the pyramid of each contact has an edge exactly along +z
    edges = pyramid_edges(contacts.normals, contacts.mu, 4)
    assert np.any(np.abs(edges[:, :, 2] - mu / math.sqrt(1 + mu * mu)) < 1e-12, axis=1).all()
    for a3 in (0.1, 1e-6):
        cfg = ContactQPConfig(alpha3=a3, alpha4=0.1)
        for solver in (ContactForceQP(cfg), ReferenceContactQP(cfg)):
            res = solver.solve(contacts, np.zeros(3), [0, 0, weight], np.zeros(3))
            assert res.found
            v = weight / (2 + a3 * (1 + 1 / mu**2))
            np.testing.assert_allclose(res.forces, [[v / mu, 0, v], [-v / mu, 0, v]],
                                       atol=1e-6)
            np.testing.assert_allclose(res.torsion, 0, atol=1e-9)
            np.testing.assert_allclose(res.wrench_error[3:], 0, atol=1e-9)
            assert cone_violation(contacts, res.forces) <= 1e-9
        if a3 == 1e-6:
            assert abs(res.forces[:, 2].sum() - weight) < 1e-5 * weight


def test_contact_frames_are_rotations_with_the_normal_last():
    rng = np.random.default_rng(0)
    n = rng.standard_normal((200, 3))
    n[:4] = [[0, 0, 1], [0, 0, -1], [1, 0, 0], [0, -1, 0]]
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    frames = contact_frames(n)
    np.testing.assert_allclose(np.einsum("kij,kil->kjl", frames, frames),
                               np.broadcast_to(np.eye(3), frames.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(frames), 1.0, atol=1e-12)
    np.testing.assert_array_equal(frames[:, :, 2], n)


@pytest.mark.parametrize("edges", [4, 6, 9])
def test_pyramid_edges_lie_on_the_cone(edges):
    rng = np.random.default_rng(1)
    n = rng.standard_normal((5, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    mu = rng.uniform(0.1, 1.5, 5)
    b = pyramid_edges(n, mu, edges)
    assert b.shape == (5, edges, 3)
    np.testing.assert_allclose(np.linalg.norm(b, axis=2), 1.0, atol=1e-12)
    fn = np.einsum("kej,kj->ke", b, n)
    ft = np.linalg.norm(b - fn[:, :, None] * n[:, None, :], axis=2)
    np.testing.assert_allclose(ft, mu[:, None] * fn, atol=1e-12)


def test_zero_friction_pushes_along_the_normal_only():
    contacts = ContactSet([[-0.03, 0, 0], [0.03, 0, 0]], [[1, 0, 0], [-1, 0, 0]], 0.0)
    res = ContactForceQP().solve(contacts, np.zeros(3), [0.0, 0.0, 2.0], np.zeros(3))
    assert not res.found and res.status == "unreachable"  # nothing can lift it
    np.testing.assert_allclose(res.forces, 0.0, atol=1e-12)
    np.testing.assert_allclose(res.wrench_error[:3], [0, 0, -2.0], atol=1e-12)


# -- bad input -----------------------------------------------------------------------------

@pytest.mark.parametrize("bad", [
    dict(points=[[0, 0, np.nan]], normals=[[1, 0, 0]], mu=0.5),
    dict(points=[[0, 0, 0]], normals=[[np.inf, 0, 0]], mu=0.5),
    dict(points=[[0, 0, 0]], normals=[[0, 0, 0]], mu=0.5),
    dict(points=[[0, 0, 0], [1, 0, 0]], normals=[[1, 0, 0]], mu=0.5),
    dict(points=[[0, 0]], normals=[[1, 0, 0]], mu=0.5),
    dict(points=[[0, 0, 0]], normals=[[1, 0, 0]], mu=[0.5, 0.5]),
    dict(points=[[0, 0, 0]], normals=[[1, 0, 0]], mu=-0.1),
    dict(points=[[0, 0, 0]], normals=[[1, 0, 0]], mu="x"),
    dict(points=[[0, 0, 0]], normals=[[1, 0, 0]], mu=0.5, forces=[[1, 0]]),
    dict(points=[[0, 0, 0]], normals=[[1, 0, 0]], mu=0.5, jacp=np.zeros((1, 3, 4)),
         jacr=np.zeros((1, 3, 5))),
])
def test_bad_contacts_raise_input_error(bad):
    with pytest.raises(InputError):
        ContactSet(**bad)


@pytest.mark.parametrize("name", ["dissertation", "seed000"])
@pytest.mark.parametrize("args", [
    (np.zeros(3), [0, 0, np.nan], np.zeros(3)),
    (np.zeros(3), [0, 0, 1.0], [np.inf, 0, 0]),
    ([0, 0], [0, 0, 1.0], np.zeros(3)),
    (np.zeros(3), [0, 0, 1.0, 0], np.zeros(3)),
    (np.zeros(3), "up", np.zeros(3)),
])
def test_bad_targets_raise_input_error(name, args):
    contacts = ContactSet(pinch().points, pinch().normals, 0.5, forces=np.ones((2, 3)))
    for solver in (ContactForceQP(CONFIGS[name]), ReferenceContactQP(CONFIGS[name])):
        with pytest.raises(InputError):
            solver.solve(contacts, *args)


def test_seed000_without_simulator_forces_is_an_input_error():
    with pytest.raises(InputError, match="seed000"):
        ContactForceQP(CONFIGS["seed000"]).solve(pinch(), np.zeros(3), [0, 0, 1], np.zeros(3))


def test_not_a_contact_set_is_an_input_error():
    with pytest.raises(InputError):
        ContactForceQP().solve([[0, 0, 0]], np.zeros(3), [0, 0, 1], np.zeros(3))


@pytest.mark.parametrize("field,value", [
    ("method", "lcp"), ("friction_edges", 3), ("alpha3", 0.0), ("alpha1", -1.0),
    ("lambda1", 0.0), ("torsional_friction", -0.1), ("max_iter", -1), ("alpha2", math.nan),
])
def test_bad_config_raises_config_error(field, value):
    with pytest.raises(ConfigError, match=field):
        ContactQPConfig(**{field: value})


# -- statuses: never NaN, found=False --------------------------------------------------------

def test_no_contacts_is_not_found():
    empty = ContactSet(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))
    res = ContactForceQP().solve(empty, np.zeros(3), [0, 0, 1.0], np.zeros(3))
    assert not res.found and res.status == "no_contacts"
    assert res.forces.shape == (0, 3)
    np.testing.assert_allclose(res.wrench_error, [0, 0, -1.0, 0, 0, 0])


@pytest.mark.parametrize("name", ["dissertation", "seed000"])
def test_iteration_cap_gives_not_found_without_nan(name):
    cfg = ContactQPConfig(method=name, max_iter=1)
    contacts, com, tf, tt = random_problems(seed=2, n=4)[3]  # 5 contacts
    res = ContactForceQP(cfg).solve(contacts, com, tf, tt)
    assert not res.found and res.status == "max_iter"
    assert np.isfinite(res.forces).all() and np.isfinite(res.torsion).all()
    np.testing.assert_array_equal(res.forces, 0.0)
    assert np.isfinite(res.residual)


def test_overflowing_problem_is_not_found_without_nan():
    """Finite but absurd inputs overflow while the problem is built: found False, no NaN."""
    contacts = ContactSet([[-1e300, 0, 0], [1e300, 0, 0]], [[1, 0, 0], [-1, 0, 0]], 0.5)
    with np.errstate(all="ignore"):
        res = ContactForceQP().solve(contacts, np.zeros(3), [0, 0, 1e300], [1e300, 0, 0])
    assert not res.found and res.status in ("non_finite", "inaccurate")
    assert np.isfinite(res.forces).all() and np.isfinite(res.torsion).all()


def test_seed000_overflow_is_not_found_without_nan():
    contacts = ContactSet([[-1e300, 0, 0], [1e300, 0, 0]], [[1, 0, 0], [-1, 0, 0]], 0.5,
                          forces=[[1e300, 0, 1e300], [-1e300, 0, 1e300]])
    with np.errstate(all="ignore"):
        res = ContactForceQP(CONFIGS["seed000"]).solve(
            contacts, np.zeros(3), [0, 0, 1e300], [1e300, 0, 0])
    assert not res.found and res.status in ("non_finite", "inaccurate")
    assert np.isfinite(res.forces).all() and np.isfinite(res.torsion).all()


@pytest.mark.filterwarnings("ignore:Solution may be inaccurate")
def test_reference_solver_that_stops_early_is_not_found():
    ref = ReferenceContactQP(solver="OSQP", solver_options={"max_iter": 2, "polishing": False})
    contacts, com, tf, tt = random_problems(seed=4, n=2)[1]
    res = ref.solve(contacts, com, tf, tt)
    assert not res.found and res.status != "optimal"
    np.testing.assert_array_equal(res.forces, 0.0)


def test_control_path_loads_no_cvxpy():
    """cvxpy (the reference) is imported lazily: the control loop never pays for it."""
    code = ("import sys, hand_control.contact, hand_control.control, hand_control.bench.contact;"
            "print('cvxpy' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=Path(__file__).resolve().parents[1])
    assert out.stdout.strip() == "False"


@pytest.mark.parametrize("name", ["dissertation", "torsion_bound"])
def test_warm_start_on_a_slowly_varying_sequence_gives_the_cold_solution(name):
    """The control loop's case: the problem drifts a little per step, the warm start (last
    passive set) answers most solves, and every answer is the cold solver's and cvxpy's."""
    cfg = CONFIGS[name]
    warm, ref = ContactForceQP(cfg), ReferenceContactQP(cfg)
    contacts, com, tf, tt = random_problems(seed=5, n=1)[0]
    rng = np.random.default_rng(8)
    dp, dn = rng.standard_normal((2, len(contacts), 3))
    for step in range(30):
        drift = 2e-4 * step  # a smooth motion, as between two 1 ms steps
        moved = ContactSet(contacts.points + drift * dp, contacts.normals + drift * dn,
                           contacts.mu)
        target_f = tf + drift * np.array([0.0, 0.0, 1.0])
        a = warm.solve(moved, com, target_f, tt)
        b = ContactForceQP(cfg).solve(moved, com, target_f, tt)  # cold: no passive set yet
        assert a.found and b.found and a.status == "optimal"
        np.testing.assert_allclose(a.forces, b.forces, rtol=0, atol=1e-9)
        np.testing.assert_allclose(a.torsion, b.torsion, rtol=0, atol=1e-9)
        assert a.objective == pytest.approx(b.objective, rel=1e-9, abs=1e-12)
        if step % 10 == 0:
            c = ref.solve(moved, com, target_f, tt)
            np.testing.assert_allclose(a.forces, c.forces, rtol=0, atol=1e-6)
            np.testing.assert_allclose(a.torsion, c.torsion, rtol=0, atol=1e-6)
    assert warm.warm_hits >= 20  # the warm start did the work


def test_trusted_solve_skips_only_the_checks():
    contacts, com, tf, tt = random_problems(seed=6, n=1)[0]
    qp = ContactForceQP(CONFIGS["torsion_bound"])
    a = qp.solve(contacts, com, tf, tt)
    fast = ContactSet.trusted(contacts.points, contacts.normals, contacts.mu)
    b = ContactForceQP(CONFIGS["torsion_bound"]).solve(fast, com, tf, tt, check=False)
    np.testing.assert_array_equal(a.forces, b.forces)
    np.testing.assert_array_equal(a.torsion, b.torsion)


@pytest.mark.parametrize("fallback", ["nnls", "osqp"])
def test_fallback_answers_when_the_active_set_hits_its_cap(fallback):
    """max_iter=1 stops the warm-started active set; OSQP (finding the active set, then the
    exact KKT-checked solve) rescues the step, scipy's NNLS obeys the same cap and fails."""
    cfg = ContactQPConfig(max_iter=1, fallback=fallback, torsion_bound=True)
    ref = ReferenceContactQP(ContactQPConfig(torsion_bound=True))
    qp = ContactForceQP(cfg)
    contacts, com, tf, tt = random_problems(seed=2, n=4)[3]
    res = qp.solve(contacts, com, tf, tt)
    if fallback == "nnls":
        assert not res.found and res.status == "max_iter"
        np.testing.assert_array_equal(res.forces, 0.0)
    else:
        assert res.found and res.status == "optimal" and qp.fallback_solves == 1
        b = ref.solve(contacts, com, tf, tt)
        np.testing.assert_allclose(res.forces, b.forces, rtol=0, atol=1e-6)
        np.testing.assert_allclose(res.torsion, b.torsion, rtol=0, atol=1e-6)


def test_no_fallback_reports_the_failure():
    cfg = ContactQPConfig(max_iter=1, fallback="none")
    contacts, com, tf, tt = random_problems(seed=2, n=4)[3]
    res = ContactForceQP(cfg).solve(contacts, com, tf, tt)
    assert not res.found and res.status == "max_iter"
    assert np.isfinite(res.forces).all()


def test_warm_start_from_a_stale_passive_set_still_gives_the_optimum():
    """The last passive set belongs to a very different problem (the target flips, every
    coefficient on it goes negative): the warm start shrinks to nothing and the active set
    rebuilds the solution; zero target -> zero forces."""
    cfg = CONFIGS["torsion_bound"]
    qp, ref = ContactForceQP(cfg), ReferenceContactQP(cfg)
    contacts, com, tf, tt = random_problems(seed=9, n=1)[0]
    for target in (tf, -tf, np.zeros(3), tf):
        a, b = qp.solve(contacts, com, target, tt), ref.solve(contacts, com, target, tt)
        assert a.status == b.status and a.status in ("optimal", "unreachable")
        np.testing.assert_allclose(a.forces, b.forces, rtol=0, atol=1e-6)
        np.testing.assert_allclose(a.torsion, b.torsion, rtol=0, atol=1e-6)


@pytest.mark.parametrize("name", ["dissertation", "torsion_bound"])
def test_solve_arrays_and_the_fast_result(name):
    """The control loop's entry (arrays, the target wrench as floats) gives solve()'s result;
    the fast result's contact wrench is (f_k, r_k x f_k + l_k n_k), its diagnostics (computed
    when read) those of the forces, and it copies, pickles and replaces like any result."""
    import copy
    import dataclasses
    import pickle

    cfg = CONFIGS[name]
    for contacts, com, tf, tt in random_problems(seed=11, n=8):
        a = ContactForceQP(cfg).solve(contacts, com, tf, tt)
        qp = ContactForceQP(cfg)
        b = qp.solve_arrays(contacts.points, contacts.normals, contacts.mu, com,
                            tf.tolist() + tt.tolist())
        c = qp.solve_arrays(contacts.points, contacts.normals, contacts.mu, com,
                            tf.tolist() + tt.tolist())  # warm
        for res in (b, c):
            assert res.found and res.status == "optimal"
            np.testing.assert_allclose(res.forces, a.forces, rtol=0, atol=1e-9)
            np.testing.assert_allclose(res.torsion, a.torsion, rtol=0, atol=1e-9)
        r = contacts.points - com
        moment = np.cross(r, c.forces) + c.torsion[:, None] * contacts.normals
        np.testing.assert_allclose(c.contact_wrench, np.hstack((c.forces, moment)), atol=1e-12)
        np.testing.assert_allclose(c.wrench_error, np.r_[c.forces.sum(0) - tf,
                                                         moment.sum(0) - tt], atol=1e-12)
        assert c.residual == pytest.approx(np.linalg.norm(c.wrench_error))
        assert c.objective == pytest.approx(
            objective_iii23(cfg, contacts, com, tf, tt, c.forces, c.torsion), rel=1e-9)
        for other in (copy.copy(c), copy.deepcopy(c), pickle.loads(pickle.dumps(c))):
            np.testing.assert_array_equal(other.wrench_error, c.wrench_error)
            assert other.objective == c.objective and other.residual == c.residual
        plain = dataclasses.replace(c, status="x")
        assert plain.status == "x" and plain.objective == c.objective
    assert qp.warm_hits >= 1


@pytest.mark.parametrize("name", ["dissertation", "torsion_bound"])
@pytest.mark.parametrize("scale", [1e-4, 1e6])
def test_acceptance_is_scale_invariant(name, scale):
    """A target s times larger has the solution s times larger: the warm-started solver, its
    passive set left by a different problem of the same contact count, must find it to the
    cold solver's relative accuracy at any scale (the KKT test used to scale with |b|^2 and
    accepted a stale passive set a few % off at 1e6 N)."""
    cfg = dataclasses.replace(CONFIGS[name], alpha3=1e-3, alpha4=1e-3)
    warm = ContactForceQP(cfg)
    for contacts, com, tf, tt in random_problems(seed=3, n=120):
        cold = ContactForceQP(cfg).solve(contacts, com, tf, tt)
        a = warm.solve(contacts, com, scale * tf, scale * tt)
        assert a.found == cold.found
        if not cold.found:
            continue
        atol = 1e-9 * scale * max(1.0, float(np.abs(cold.forces).max()))
        np.testing.assert_allclose(a.forces, scale * cold.forces, rtol=0, atol=atol)
        np.testing.assert_allclose(a.torsion, scale * cold.torsion, rtol=0, atol=atol)


def _pushing_contact() -> tuple[ContactSet, np.ndarray]:
    """One fingertip under the object, pushing up (+z), 2 cm below its centre of mass."""
    return ContactSet([[0.0, 0.0, -0.02]], [[0.0, 0.0, 1.0]], [0.5]), np.zeros(3)


@pytest.mark.parametrize("name", list(CONFIGS))
@pytest.mark.parametrize("solver", ["fast", "fast_arrays", "reference"])
def test_a_pull_through_a_pushing_contact_is_unreachable(name, solver):
    """The contact can only push: a downward pull is out of reach. The optimum is no force
    at all, which must be reported (status 'unreachable', found False, its residual the whole
    target), not as an optimal solution; an upward push of the same size is reached."""
    cfg = CONFIGS[name]
    contacts, com = _pushing_contact()
    contacts = ContactSet(contacts.points, contacts.normals, contacts.mu,
                          forces=[[0.0, 0.0, 2.0]])
    for target, reachable in (([0.0, 0.0, -2.0], False), ([0.0, 0.0, 2.0], True)):
        tf, tt = np.array(target), np.zeros(3)
        if solver == "reference":
            res = ReferenceContactQP(cfg).solve(contacts, com, tf, tt)
        elif solver == "fast_arrays" and cfg.method == "dissertation":
            res = ContactForceQP(cfg).solve_arrays(contacts.points, contacts.normals,
                                                   contacts.mu, com, list(tf) + list(tt))
        else:
            res = ContactForceQP(cfg).solve(contacts, com, tf, tt)
        if reachable:
            assert res.found and res.status == "optimal", res.status
            assert res.forces[0, 2] > 0.5 and res.residual < 0.9 * 2.0
        else:
            assert not res.found and res.status == "unreachable", res.status
            assert res.residual == pytest.approx(2.0, rel=1e-6)
            np.testing.assert_allclose(res.forces, 0.0, atol=1e-6)


def test_a_mostly_unreachable_target_is_flagged_by_the_configured_ratio():
    """A pull with a small push component: the contact applies only the push, the residual
    is ~99 % of the target; flagged at the default ratio 0.9, accepted at 1.0 only if the
    residual is below the whole target."""
    contacts, com = _pushing_contact()
    tf, tt = np.array([0.0, 0.0, 0.0]), np.zeros(3)
    tf[:] = [2.0, 0.0, -0.5]  # a sideways pull the pyramid (mu 0.5) mostly cannot give
    res = ContactForceQP(ContactQPConfig()).solve(contacts, com, tf, tt)
    assert res.status == "unreachable" and not res.found
    rel = res.residual / np.linalg.norm(tf)
    assert 0.9 <= rel < 1.0
    # the forces are the optimum's (the closest wrench the contact can apply), not zeros
    assert res.forces[0, 2] > 0.0
    lenient = ContactForceQP(ContactQPConfig(unreachable_residual=1.0)).solve(
        contacts, com, tf, tt)
    assert lenient.found and lenient.status == "optimal"


@pytest.mark.parametrize("name", ["dissertation", "seed000"])
def test_recorder_sees_every_solve_through_either_entry_point(name):
    """The benchmark records the control loop's problems through ``recorder``: both entry
    points (``solve`` and the loop's ``solve_arrays``) report each problem once, before
    solving, and recording changes no result."""
    cfg = CONFIGS[name]
    seen = []
    qp, plain = ContactForceQP(cfg), ContactForceQP(cfg)
    qp.recorder = lambda c, com, tf, tt: seen.append((c.points.copy(), tf.copy(), tt.copy()))
    problems = random_problems(seed=12, n=6)
    for contacts, com, tf, tt in problems:
        a = qp.solve(contacts, com, tf, tt)
        if name == "dissertation":  # solve_arrays takes no simulator forces
            b = qp.solve_arrays(contacts.points, contacts.normals, contacts.mu, com,
                                tf.tolist() + tt.tolist())
            np.testing.assert_allclose(a.forces, b.forces, rtol=0, atol=1e-12)
        np.testing.assert_allclose(a.forces, plain.solve(contacts, com, tf, tt).forces,
                                   rtol=0, atol=1e-12)
    per = 2 if name == "dissertation" else 1
    assert len(seen) == per * len(problems)
    for i, (contacts, _, tf, tt) in enumerate(problems):
        pts, f, t = seen[per * i]
        np.testing.assert_array_equal(pts, contacts.points)
        np.testing.assert_array_equal(f, tf)
        np.testing.assert_array_equal(t, tt)
