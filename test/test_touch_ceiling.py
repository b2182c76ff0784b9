"""scripts/touch_label_ceiling.py (analysis of the held-out family, never shipped): its
features and classes on frames with known answers."""

from __future__ import annotations

import numpy as np
from script_helpers import load_script


def _script():
    return load_script("touch_label_ceiling")


def test_ceiling_classes_name_every_finger_in_surface_x_order():
    ceil = _script()
    reported = np.zeros((3, 5, 2))
    contact = np.zeros((3, 5), bool)
    contact[0, [0, 2]] = True                 # thumb right of the middle finger
    reported[0, 0], reported[0, 2] = (0.09, 0.05), (0.05, 0.08)
    contact[1, [0, 1, 4]] = True              # thumb, index, little
    reported[1, [0, 1, 4]] = [(0.02, 0.02), (0.05, 0.09), (0.11, 0.06)]
    contact[2, [1, 2]] = True                 # index, middle, turned by 90 deg
    reported[2, 1], reported[2, 2] = (0.10, 0.05), (0.10, 0.07)
    x, keys = ceil.features(reported, contact, 2)
    # the thumb (finger 0) is kept: in x order middle then thumb, then index then middle
    assert list(keys) == [120, 112]
    assert [ceil._set_name(k) for k in keys] == ["T+M", "I+M"]
    # centred surface positions, the contacts' own frame, the distance
    np.testing.assert_allclose(x[0, :4], [-0.02, 0.015, 0.02, -0.015])
    np.testing.assert_allclose(x[0, 4:8], [-0.025, 0.0, 0.025, 0.0], atol=1e-12)
    np.testing.assert_allclose(x[:, 8], [0.05, 0.02])
    # the same layout turned on the surface gives the same own-frame features
    np.testing.assert_allclose(np.abs(x[1, 4:8]), [0.01, 0.0, 0.01, 0.0], atol=1e-12)
    x3, keys3 = ceil.features(reported, contact, 3)
    assert list(keys3) == [1014] and ceil._set_name(keys3[0]) == "T+I+L"
    assert x3.shape == (1, 6 + 6 + 3)
