"""_Layout.gathers: the per-passive-set entries the warm start reads, the picker included."""

from __future__ import annotations

import numpy as np

from hand_control.contact.qp import ContactForceQP, ContactQPConfig


def test_gathers_pick_the_passive_entries_for_every_set_size() -> None:
    qp = ContactForceQP(ContactQPConfig(torsion_bound=True))
    lay = qp._layout(np.array([0.8, 0.5, 1.0]))
    values = [float(i) * 1.5 - 7.0 for i in range(lay.n)]
    for p in ([4], [0, 9], [1, 2, 6, 16, 23, 8, 19, 21], list(range(lay.n))):
        ent = lay.gathers(p)
        assert list(ent[5](values)) == [values[i] for i in p]
        np.testing.assert_array_equal(ent[0], p + [lay.n])
        assert lay.gathers(list(p)) is ent  # cached per passive set
    assert list(lay.gathers([])[5](values)) == []


def test_solve_arrays_failure_matches_the_contact_set_path() -> None:
    """A target that overflows the problem: solve_arrays (lever arms as rows of floats) gives
    the same failed result as solve on a ContactSet."""
    from hand_control.contact import ContactSet

    qp = ContactForceQP()
    points = np.array([[0.02, 0.0, 0.0], [-0.02, 0.0, 0.0], [0.0, 0.02, 0.01]])
    normals = np.array([[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    mu = np.array([0.8, 0.8, 0.8])
    com = np.array([0.0, 0.0, 0.005])
    wrench = [1e200, 0.0, 0.0, 0.0, 0.0, 0.0]
    with np.errstate(over="ignore"):  # the residual of the failed result overflows too
        fast = qp.solve_arrays(points, normals, mu, com, wrench)
        plain = qp.solve(ContactSet(points, normals, mu), com, wrench[0:3], wrench[3:6])
    assert not fast.found and fast.status == plain.status == "non_finite"
    np.testing.assert_array_equal(fast.forces, np.zeros((3, 3)))
    np.testing.assert_array_equal(fast.wrench_error, plain.wrench_error)
    # a solvable target: the same forces both ways
    wrench = [0.0, 0.0, 2.0, 0.0, 0.0, 0.0]
    fast = qp.solve_arrays(points, normals, mu, com, wrench)
    qp._passive.clear()
    plain = qp.solve(ContactSet(points, normals, mu), com, wrench[0:3], wrench[3:6])
    assert fast.found and plain.found
    np.testing.assert_array_equal(fast.forces, plain.forces)
    np.testing.assert_array_equal(fast.torsion, plain.torsion)
