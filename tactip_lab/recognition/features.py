"""Tactile observations from contacts: the marker field (for the bag of features and the
marker selection) and the difference image (for the moment descriptors and the CNN).

Marker field, one vector per contact: for every pin seen at rest, its displacement (dx, dy)
in px and its Voronoi cell growth (area / rest area - 1), i.e. ``3 p`` numbers in pin order.
These are the TacTip's own sensing elements: the same ~97 numbers a real rig's perception gives,
in a fixed order, so two contacts compare element by element like the 6 x 14 pressure images
of the bag-of-features paper; they ignore lighting and camera noise that a raw frame carries.

A marker lost in a contact (perception could not track it: pushed together with a neighbour
or out of focus at a deep press) gets the mean of its tracked neighbours within 1.5 rest
spacings (repeated outwards, at most 4 passes; 0 where none is tracked): a lost marker sits
where the pad deforms most, so 0 would mark the place of largest deformation as undeformed.
"""

from __future__ import annotations

import numpy as np

CHANNELS = ("dx", "dy", "growth")
NEIGHBOUR_SPACINGS = 1.5
FILL_PASSES = 4


def visible_pins(rest_pins_px: np.ndarray) -> np.ndarray:
    """(q,) indices of the pins seen at rest (finite rest position)."""
    return np.flatnonzero(np.isfinite(rest_pins_px).all(axis=1))


def fill_lost(values: np.ndarray, rest_px: np.ndarray) -> np.ndarray:
    """Fill NaN entries of per-marker ``values`` (n, q, c) with their tracked neighbours'
    mean (see the module docstring); ``rest_px`` (q, 2) the markers at rest."""
    from scipy.spatial import cKDTree

    v = np.array(values, dtype=float)
    if v.ndim == 2:
        v = v[..., None]
    tree = cKDTree(rest_px)
    d, _ = tree.query(rest_px, k=2)
    spacing = float(np.median(d[:, 1]))
    pairs = tree.query_pairs(NEIGHBOUR_SPACINGS * spacing, output_type="ndarray")
    adj = np.zeros((len(rest_px), len(rest_px)))
    adj[pairs[:, 0], pairs[:, 1]] = adj[pairs[:, 1], pairs[:, 0]] = 1.0
    for _ in range(FILL_PASSES):
        lost = ~np.isfinite(v).all(axis=2)  # (n, q)
        if not lost.any():
            break
        known = (~lost).astype(float)
        total = np.einsum("qr,nrc->nqc", adj, np.where(lost[..., None], 0.0, v))
        count = known @ adj.T  # (n, q)
        fill = total / np.maximum(count, 1.0)[..., None]
        v = np.where((lost & (count > 0))[..., None], fill, v)
    return np.nan_to_num(v, nan=0.0)


def marker_field(disp_px: np.ndarray, growth: np.ndarray, rest_pins_px: np.ndarray
                 ) -> np.ndarray:
    """(n, q, 3) dx, dy (px) and growth of the pins seen at rest, lost ones filled.

    Parameters
    ----------
    disp_px : (n, p, 2) pin displacements; growth : (n, p) cell growth
    rest_pins_px : (p, 2) pins at rest (NaN: not seen)
    """
    pins = visible_pins(rest_pins_px)
    raw = np.concatenate([disp_px[:, pins], growth[:, pins, None]], axis=2)
    return fill_lost(raw, rest_pins_px[pins])


class FieldScaler:
    """Scale the marker field per channel kind: displacements by their RMS over the training
    contacts (one scale for dx and dy), growth by its RMS, then flatten to (n, 3 q). One scale
    per kind, not per marker: a marker that rarely moves keeps its small values instead of
    having its noise blown up to unit variance."""

    def fit(self, field: np.ndarray) -> FieldScaler:
        disp = field[..., :2]
        self.disp_scale_ = float(np.sqrt(np.mean(disp**2))) or 1.0
        self.growth_scale_ = float(np.sqrt(np.mean(field[..., 2] ** 2))) or 1.0
        return self

    def transform(self, field: np.ndarray) -> np.ndarray:
        out = np.array(field, dtype=float)
        out[..., :2] /= self.disp_scale_
        out[..., 2] /= self.growth_scale_
        return out.reshape(len(out), -1)


def difference_images(images: np.ndarray, rest_image: np.ndarray) -> np.ndarray:
    """(n, h, w) float32: each downsampled frame minus the rest frame, / 255 (signed)."""
    return (images.astype(np.float32) - rest_image.astype(np.float32)[None]) / 255.0


__all__ = ["CHANNELS", "FieldScaler", "difference_images", "fill_lost", "marker_field",
           "visible_pins"]
