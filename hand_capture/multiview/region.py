"""Object region score: how much of an object's rendered silhouette shows the object's colour.

Seed 000 (sec. 4.2, eq. 4-5) compares a rendered silhouette with an observed one that a colour
model learned on the first frame draws. Here the same colour model (:class:`~hand_capture.
multiview.imageterms.ColourModel`, eq. 4: a super-Gaussian mixture of the object's colours
against one of everything else in view, hands included) is learned per rigid object on a frame
whose configuration is known or well tracked, and a hypothesised object pose is scored by

    region = sum_v |S_r,v & O_v| / sum_v (|S_r,v| + |B_v & O_v|)

where ``S_r,v`` is the object's visible rendered silhouette in view ``v`` (the scene rendered
with the tracked hands, so pixels a hand hides do not count), ``O_v`` the pixels whose image
colour the object's mixture explains better than the rest's (eq. 4, per pixel, no opening)
and ``B_v`` a band ``band_px`` wide around ``S_r,v`` where nothing is rendered: eq. (5)'s
two-way silhouette discrepancy kept local (object colour in the band is object the pose
misses; other objects of that colour elsewhere in the image do not count), pooled over the
cameras by pixel count. A pose on an object's image region scores near 1 in every view; a
pose beside it (on a hand, on the background, on a clutter circle whose edges happen to fit
the outline) scores near 0, which edge support cannot tell apart (the edges of a disc of the
object's size fit its outline anywhere).

:meth:`ObjectRegions.blob_masks` also gives each view's object-colour blobs (opened), from which
:func:`~hand_capture.multiview.hull.place_object` intersects a visual hull and places the
object: a candidate pose for a lost object wherever it went.

Everything runs at ``scale`` times the camera resolution (0.25: 160 x 120 for the studio): the
ball's silhouette still covers about a hundred pixels a view, and a render costs little.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from hand_capture.errors import InputError
from hand_capture.multiview.imageterms import ColourModel
from hand_capture.multiview.rig import Rig
from hand_capture.multiview.scene_model import SceneModel

__all__ = ["ObjectRegions"]


class ObjectRegions:
    """Per-object colour models (eq. 4) and the region score of object poses.

    Args:
        model: the combined model (objects are parts ``n_hands ..``).
        rig: the cameras.
        scale: resolution of the renders and colour maps (share of the image).
        min_pixels: fewer visible silhouette pixels than this over all views (at ``scale``)
            give no score (NaN): an object hidden by the hands or out of view says nothing.
        margin_px: band left out on both sides of each learned silhouette's outline [px at
            the image resolution] (the rendered outline and anti-aliased rims mix colours).
        band_px: width of the band ``B`` around the rendered silhouette [px at ``scale``]
            (0: the one-way overlap ``|S & O| / |S|``).
    """

    def __init__(self, model: SceneModel, rig: Rig, scale: float = 0.25,
                 min_pixels: int = 40, margin_px: int = 3, band_px: int = 4) -> None:
        if not 0.05 <= scale <= 1.0:
            raise InputError(f"ObjectRegions: scale must be in [0.05, 1], got {scale}")
        self.model = model
        self.rig = rig
        self.scale = float(scale)
        self.min_pixels = int(min_pixels)
        self.margin_px = int(margin_px)
        self.band_px = int(band_px)
        #: object part index -> its colour model (against everything else in view)
        self.colours: dict[int, ColourModel] = {}

    # ------------------------------------------------------------------------- learning
    def learn(self, images: Mapping[str, np.ndarray | None], params: np.ndarray,
              parts: Sequence[int]) -> list[int]:
        """Fit the colour model of each object part in ``parts`` (not learned yet) on
        ``images`` seen at the configuration ``params`` (its visible rendered silhouettes,
        hands drawn in front, ``margin_px`` of each outline left out); a view needs 50
        silhouette pixels, and a model is kept only when it explains most of the object's
        pixels and few of the others' on these images. Returns the parts learned now."""
        import cv2

        m = self.model
        todo = [p for p in parts if p >= m.n_hands and p not in self.colours]
        if not todo:
            return []
        state = m.pose(params)
        views = []
        for cam in self.rig.cameras:
            img = images.get(cam.name)
            if img is None:
                continue
            a = np.asarray(img)
            ren = m.render(cam, state, 0.5)
            views.append((a, cv2.resize(ren.labels, (a.shape[1], a.shape[0]),
                                        interpolation=cv2.INTER_NEAREST)))
        done = []
        for p in todo:
            imgs, masks = [], []
            for a, lab in views:
                mask = lab == p + 1
                if mask.sum() > 50:
                    imgs.append(a)
                    masks.append(mask)
            if not imgs:
                continue
            col = ColourModel.fit(imgs, masks, margin_px=self.margin_px)
            # kept only when it tells the object from the rest on the very frame it was
            # learned on (a dark or washed-out frame teaches nothing)
            hit = [col.explains(a) for a in imgs]
            inside = np.mean(np.concatenate([h[mk] for h, mk in zip(hit, masks, strict=True)]))
            outside = np.mean(np.concatenate([h[~mk] for h, mk in zip(hit, masks,
                                                                       strict=True)]))
            if inside > 0.5 and outside < 0.5:
                self.colours[p] = col
                done.append(p)
        return done

    # ---------------------------------------------------------------------- per frame
    def maps(self, images: Mapping[str, np.ndarray | None]) -> dict[int, dict[int, np.ndarray]]:
        """Per learned object part, per present camera index: (h, w) bool at ``scale``, the
        pixels whose colour the object's mixture explains (eq. 4, no opening)."""
        import cv2

        out: dict[int, dict[int, np.ndarray]] = {p: {} for p in self.colours}
        if not self.colours:
            return out
        for c, cam in enumerate(self.rig.cameras):
            img = images.get(cam.name)
            if img is None or np.ndim(img) != 3:
                continue
            k = cam.intrinsics
            w, h = int(round(k.width * self.scale)), int(round(k.height * self.scale))
            small = cv2.resize(np.asarray(img), (w, h), interpolation=cv2.INTER_AREA)
            for p, col in self.colours.items():
                out[p][c] = col.explains(small)
        return out

    def score(self, params: np.ndarray, maps: Mapping[int, Mapping[int, np.ndarray]],
              part: int, parts: Sequence[int] | None = None) -> tuple[float, int]:
        """Region score of object ``part`` at ``params`` (module docstring) and its visible
        silhouette pixels over all views (at ``scale``); NaN below ``min_pixels`` or without
        a colour model. ``parts``: the parts rendered (default: all; those left out, e.g.
        lost hands, hide nothing)."""
        if part not in self.colours or part not in maps:
            return float("nan"), 0
        state = self.model.pose(params)
        draw = sorted(set(range(len(self.model.part_names)) if parts is None else parts)
                      | {part})
        import cv2

        n = hit = miss = 0
        k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * self.band_px + 1,) * 2)
        for c, om in maps[part].items():
            ren = self.model.render(self.rig.cameras[c], state, self.scale, parts=draw)
            sil = ren.labels == part + 1
            if sil.shape != om.shape:
                raise InputError(f"render {sil.shape} and colour map {om.shape} differ")
            n += int(sil.sum())
            hit += int(np.count_nonzero(om[sil]))
            if self.band_px > 0 and sil.any():
                band = (cv2.dilate(sil.astype(np.uint8), k) > 0) & (ren.labels == 0)
                miss += int(np.count_nonzero(om[band]))
        if n < self.min_pixels:
            return float("nan"), n
        return hit / (n + miss), n

    def blob_masks(self, maps: Mapping[int, Mapping[int, np.ndarray]], part: int
                   ) -> dict[str, np.ndarray]:
        """Camera name -> (H, W) bool at the camera's resolution: the object-colour pixels
        of ``part`` opened with a 3 x 3 square at ``scale`` (speckle and anti-aliased rims
        of other edges drop out), for a visual hull."""
        import cv2

        out = {}
        k3 = np.ones((3, 3), np.uint8)
        for c, om in maps.get(part, {}).items():
            cam = self.rig.cameras[c]
            m = cv2.morphologyEx(om.astype(np.uint8), cv2.MORPH_OPEN, k3)
            k = cam.intrinsics
            out[cam.name] = cv2.resize(m, (k.width, k.height),
                                       interpolation=cv2.INTER_NEAREST) > 0
        return out
