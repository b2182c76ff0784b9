"""``hand-suite bench rgb``: the colour-camera hand tracker on rendered colour images.

Runs :func:`hand_capture.rgbtrack.evaluate.rgb_tracker_figures` (module docstring there: the
suite renderer's images and the independent held-out surfaces of ``hand_capture.evaldata``
shaded in colour; detector + fit speed against the detector alone in the same run). The same
figures appear in ``hand-suite bench retarget``.
"""

from __future__ import annotations

from typing import Any


def run(quick: bool = False, smoke: bool = False) -> dict[str, Any]:
    """Print the tables; return the figures for the last JSON line."""
    from hand_capture.rgbtrack.evaluate import rgb_tracker_figures

    return rgb_tracker_figures(quick=quick, smoke=smoke, verbose=True)
