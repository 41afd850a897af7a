"""Marker tracking: keep each marker's identity from the rest frame through a sequence.

Each frame is matched to the tracks by an optimal one-to-one assignment
(``scipy.optimize.linear_sum_assignment``) with a distance gate:

* a track seen in the previous frame is predicted at its last position plus its last
  frame-to-frame motion (constant velocity), so shear that builds up over many frames is
  followed without the gate having to cover the total displacement;
* a lost track is looked for at its last known position *and* at its rest position (the skin
  relaxes back), whichever is closer;
* the gate is a fraction of the rest marker spacing (default one half: no detection can then
  be within the gate of two rest neighbours);
* the assignment maximises the number of gated matches first and then minimises the total
  distance (a cost above the gate that exceeds any feasible total);
* unmatched tracks are **lost**: their position is NaN, never the stale last position, and
  they are re-acquired as soon as a detection reappears within the gate;
* with blob areas given, a blob larger than ``merge_area_ratio`` times the median rest area is
  a merged pair: the track it is matched to is flagged ``MERGED`` (NaN) instead of taking a
  position between two markers;
* optionally (``TrackingParams.regrow``, for frames tracked straight from a reference in
  which the skin may move by more than a spacing), an assignment that leaves tracks without
  a detection beside unmatched detections, or gives a marker a motion its neighbours do not
  share, is grown again from each of its coherent patches; the outcome with the most
  coherent matches is kept.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial.distance import cdist

from .errors import PointsError
from .geometry import as_points, marker_spacing
from .params import TrackingParams

__all__ = ["LOST", "MERGED", "TRACKED", "MarkerTracker"]

#: Track status codes (``MarkerTracker.status``).
TRACKED, LOST, MERGED = 0, 1, 2


class MarkerTracker:
    """Track markers against a rest frame.

    Parameters
    ----------
    rest_points : (m, 2) float, px, OpenCV (x, y)
        Marker positions in the rest frame; all finite, m >= 2 (the gate needs a spacing).
    rest_areas : (m,) float, px², optional
        Blob areas in the rest frame; enables merged-blob flagging when ``update`` is given
        areas.
    gate_px : float, optional
        Distance gate, px (> 0). Default ``params.gate_fraction`` times the rest spacing.
    params : TrackingParams, optional

    Attributes
    ----------
    rest_points : (m, 2) float64, px
    gate_px : float
    spacing_px : float
        Median nearest-neighbour distance of the rest points.

    Examples
    --------
    Seven markers 10 px apart; the gate is half the spacing:

    >>> import numpy as np
    >>> from perception.geometry import hex_lattice
    >>> rest_pts = hex_lattice(7, 10.0, (50.0, 50.0))
    >>> tracker = MarkerTracker(rest_pts)
    >>> round(tracker.gate_px, 6)
    5.0

    The skin moves by (2, 1) px; the detections come in another order and marker 0 is missing:

    >>> detected_pts = (rest_pts + (2.0, 1.0))[::-1][:6]
    >>> positions = tracker.update(detected_pts)   # (m, 2), NaN rows for lost markers
    >>> tracker.lost.tolist()
    [True, False, False, False, False, False, False]
    >>> tracker.last_match.tolist()                # detection row of each track, -1: none
    [-1, 5, 4, 3, 2, 1, 0]
    >>> bool(np.array_equal(positions[1:], rest_pts[1:] + (2.0, 1.0)))
    True

    It moves on by (2, 1) px: the tracked markers are looked for one step further (constant
    velocity), the lost one at its last known and its rest position, and all are found again:

    >>> positions = tracker.update(rest_pts + (4.0, 2.0))
    >>> tracker.n_lost, tracker.last_match.tolist()
    (0, [0, 1, 2, 3, 4, 5, 6])
    """

    def __init__(self, rest_points: np.ndarray, *, rest_areas: np.ndarray | None = None,
                 gate_px: float | None = None, params: TrackingParams | None = None) -> None:
        self.params = params if params is not None else TrackingParams()
        rest = as_points(rest_points, "rest_points", allow_nan=False)
        if len(rest) < 2:
            raise PointsError(f"rest_points needs at least 2 markers, got {len(rest)}")
        self.rest_points = rest
        self.rest_points.setflags(write=False)
        self.spacing_px = marker_spacing(rest)
        if gate_px is None:
            gate_px = self.params.gate_fraction * self.spacing_px
        if not (np.isfinite(gate_px) and gate_px > 0):
            raise PointsError(f"gate_px={gate_px} must be finite and > 0")
        self.gate_px = float(gate_px)
        self._rest_area = None
        if rest_areas is not None:
            ra = np.asarray(rest_areas, dtype=np.float64)
            if ra.shape != (len(rest),) or not (np.isfinite(ra).all() and (ra > 0).all()):
                raise PointsError(f"rest_areas must be {len(rest)} finite positive areas")
            self._rest_area = float(np.median(ra))
        self.reset()

    # -- state ----------------------------------------------------------------------------
    def reset(self) -> None:
        """Forget the sequence: every track back at rest, seen, with zero velocity."""
        m = len(self.rest_points)
        self._last = self.rest_points.copy()  # last known position of each track
        self._velocity = np.zeros((m, 2))
        self._seen = np.ones(m, dtype=bool)  # seen in the previous frame
        self._positions = self.rest_points.copy()
        self._status = np.zeros(m, dtype=np.int8)
        self.last_match = np.full(m, -1, dtype=np.intp)  # detection row per track, -1: none
        self.frame_index = 0

    @property
    def positions(self) -> np.ndarray:
        """(m, 2) float64, px: positions from the last update, NaN for lost/merged tracks."""
        return self._positions.copy()

    @property
    def last_known(self) -> np.ndarray:
        """(m, 2) float64, px: where each track was last seen (rest position if never lost).

        Not a position estimate for lost tracks - use it only where a placeholder is needed
        (e.g. to keep a lost marker's Voronoi cell from being absorbed by its neighbours).
        """
        return self._last.copy()

    @property
    def status(self) -> np.ndarray:
        """(m,) int8: :data:`TRACKED`, :data:`LOST` or :data:`MERGED` per track."""
        return self._status.copy()

    @property
    def lost(self) -> np.ndarray:
        """(m,) bool: tracks without a position in the last update."""
        return self._status != TRACKED

    @property
    def n_lost(self) -> int:
        """Number of tracks without a position in the last update."""
        return int(np.count_nonzero(self._status != TRACKED))

    # -- update ---------------------------------------------------------------------------
    def predicted(self) -> np.ndarray:
        """(m, 2) float64, px: where each track is expected in the next frame."""
        pred = self._last.copy()
        if self.params.use_velocity:
            pred[self._seen] += self._velocity[self._seen]
        return pred

    def update(self, points: np.ndarray, *, areas: np.ndarray | None = None) -> np.ndarray:
        """Assign this frame's detections to the tracks.

        Parameters
        ----------
        points : (n, 2) float, px, OpenCV (x, y)
            Detections in any order; NaN rows are ignored; n may be 0.
        areas : (n,) float, px², optional
            Blob areas (e.g. ``MarkerDetection.areas_px``); with ``rest_areas`` given at
            construction, oversized blobs are treated as merged pairs.

        Returns
        -------
        positions : (m, 2) float64, px
            Position of every track in this frame, NaN where the track is lost or merged.
        """
        det = as_points(points, "points")
        keep = np.isfinite(det).all(axis=1)
        merged_det = np.zeros(len(det), dtype=bool)
        if areas is not None:
            ar = np.asarray(areas, dtype=np.float64)
            if ar.shape != (len(det),):
                raise PointsError(f"areas must have shape ({len(det)},), got {ar.shape}")
            if self._rest_area is not None:
                merged_det = ar > self.params.merge_area_ratio * self._rest_area
        det_idx = np.flatnonzero(keep)
        det = det[keep]
        merged_det = merged_det[keep]

        m = len(self.rest_points)
        if self.params.coherent:
            track, match = self._assign_coherent(det)
        elif self.params.regrow:
            track, match = self._assign_regrow(det)
        else:
            track, match = self._assign(det)
        new_pos = np.full((m, 2), np.nan)
        status = np.full(m, LOST, dtype=np.int8)
        good = ~merged_det[match]
        if self.params.merge_needs_lost_neighbour and not good.all():
            good = self._no_missing_partner(track, match, det, good)
        new_pos[track[good]] = det[match[good]]
        status[track[good]] = TRACKED
        status[track[~good]] = MERGED
        if self.params.merged_pairs_share and not good.all():
            self._share_pairs(track, match, det, good, new_pos, status)

        ok = status == TRACKED
        # velocity only from consecutive sightings; re-acquired tracks restart at zero
        vel = np.zeros((m, 2))
        both = ok & self._seen
        vel[both] = new_pos[both] - self._last[both]
        self._velocity = vel
        self._last[ok] = new_pos[ok]
        self._seen = ok
        self._positions = new_pos
        self._status = status
        self.frame_index += 1
        self.last_match = np.full(m, -1, dtype=np.intp)
        self.last_match[track] = det_idx[match]
        return new_pos.copy()

    def _no_missing_partner(self, track: np.ndarray, match: np.ndarray, det: np.ndarray,
                            good: np.ndarray) -> np.ndarray:
        """``good`` with every oversized blob that has no unmatched track within the gate
        (where its pair's other marker would be expected) taken as one grown marker."""
        unmatched = np.ones(len(self.rest_points), dtype=bool)
        unmatched[track] = False
        out = good.copy()
        if not unmatched.any():
            out[:] = True
            return out
        big = np.flatnonzero(~good)
        blobs = det[match[big]]
        d = np.minimum(cdist(blobs, self.predicted()[unmatched]),
                       cdist(blobs, self.rest_points[unmatched]))
        out[big[d.min(axis=1) > self.gate_px]] = True
        return out

    def _share_pairs(self, track: np.ndarray, match: np.ndarray, det: np.ndarray,
                     good: np.ndarray, new_pos: np.ndarray, status: np.ndarray) -> None:
        """Give each merged pair's blob to both of its tracks (``merged_pairs_share``), in
        place: the matched track and the nearest unmatched one within the gate, at the
        blob's centroid ± half their predicted separation."""
        unmatched = np.ones(len(self.rest_points), dtype=bool)
        unmatched[track] = False
        pred = self.predicted()
        free = np.flatnonzero(unmatched)
        for k in np.flatnonzero(~good):
            if free.size == 0:
                return
            t, c = track[k], det[match[k]]
            d = np.minimum(np.linalg.norm(pred[free] - c, axis=1),
                           np.linalg.norm(self.rest_points[free] - c, axis=1))
            j = int(np.argmin(d))
            if d[j] > self.gate_px:
                continue
            u = free[j]
            half = 0.5 * (pred[t] - pred[u])
            new_pos[t], new_pos[u] = c + half, c - half
            status[t] = status[u] = TRACKED
            free = np.delete(free, j)

    def _rest_neighbours(self) -> np.ndarray:
        """(m, 6) int: each rest marker's lattice neighbours (within 1.5 spacings), -1 pad."""
        if getattr(self, "_nbrs", None) is None:
            from scipy.spatial import cKDTree

            m = len(self.rest_points)
            k = min(6, m - 1)
            d, i = cKDTree(self.rest_points).query(self.rest_points, k=k + 1)
            d, i = d[:, 1:].reshape(m, k), i[:, 1:].reshape(m, k)
            self._nbrs = np.where(d <= 1.5 * self.spacing_px, i, -1)
        return self._nbrs

    def _neighbour_motion(self, pred: np.ndarray, pos: np.ndarray, matched: np.ndarray,
                          rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Median displacement from prediction of each track's matched rest neighbours, and
        how many there are: ((m, 2), (m,)), or for the tracks ``rows`` only."""
        nb = self._rest_neighbours()
        if rows is not None:
            nb = nb[rows]
        nbc = np.maximum(nb, 0)
        valid = (nb >= 0) & matched[nbc]
        count = valid.sum(axis=1)
        # the median of the valid ones, as np.nanmedian gives it (NaN where none), without
        # its masked-array path: the others sorted last (inf), then the middle one or the
        # mean of the two middle ones
        disp = pos[nbc] - pred[nbc]
        disp[~valid] = np.inf
        srt = np.sort(disp, axis=1)
        r = np.arange(len(nb))
        med = (srt[r, np.maximum((count - 1) // 2, 0)] + srt[r, count // 2]) / 2.0
        med[count == 0] = np.nan
        return med, count

    def _assign_coherent(self, det: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Assignment by the skin's coherence (``TrackingParams.coherent``): plain gated
        matches that agree with their neighbours seed the frame, the rest is matched wave by
        wave at the neighbours' motion, and disagreeing matches are dropped at the end."""
        from .params import COHERENT_TOLERANCE

        m = len(self.rest_points)
        track, match = self._assign(det)
        if len(det) == 0 or len(track) == 0:
            return track, match
        pred = self.predicted()
        tol = COHERENT_TOLERANCE * self.spacing_px
        step = 0.5 * self.spacing_px
        pos = np.full((m, 2), np.nan)
        of = np.full(m, -1, dtype=np.intp)
        pos[track], of[track] = det[match], match
        matched = of >= 0
        # seeds: plain matches whose motion agrees with their matched neighbours'
        med, count = self._neighbour_motion(pred, pos, matched)
        agree = matched & (count >= 2) & (np.hypot(*(pos - pred - med).T) <= tol)
        # ... and move little, unless nothing is still (the whole array moved)
        still = agree & (np.hypot(*(pos - pred).T) <= tol)
        # ... and are reached from the rim through still markers: a region moved by about a
        # spacing can be matched one marker over, coherently and still-looking, but it is
        # cut off from the clamped rim by the band where the motion is half a spacing
        nb = self._rest_neighbours()
        reached = still & ((nb >= 0).sum(axis=1) < 5)  # the outer ring
        motion = pos - pred
        # a step to a neighbour whose motion differs by less than the tolerance (the band
        # where a region is matched one marker over is a jump of about a spacing)
        step_ok = (nb >= 0) & (np.hypot(*(motion[:, None, :] - motion[np.maximum(nb, 0)])
                                        .transpose(2, 0, 1)) <= tol)
        while True:
            grow = still & ~reached & (reached[np.maximum(nb, 0)] & step_ok).any(axis=1)
            if not grow.any():
                break
            reached |= grow
        if reached.sum() >= max(3, m // 20):
            agree = reached
        elif still.sum() >= max(3, m // 20):
            agree = still
        of[~agree] = -1
        pos[~agree] = np.nan
        matched = agree
        free = np.ones(len(det), dtype=bool)
        free[of[matched]] = False
        for _ in range(2):  # waves, the last word, and once more for the dropped tracks
            of, pos, matched, free = self._waves(det, pred, of, pos, matched, free, step,
                                                 4 * int(np.sqrt(m)) + 4)
            med, count = self._neighbour_motion(pred, pos, matched)
            off = matched & (count >= 2) & (np.hypot(*(pos - pred - med).T) > tol)
            matched &= ~off
            free[of[off]] = True
            of[off], pos[off] = -1, np.nan
        t = np.flatnonzero(matched)
        return t, of[t]

    def _incoherent(self, pred: np.ndarray, pos: np.ndarray, matched: np.ndarray,
                    tol: float) -> np.ndarray:
        """(m,) bool: matched tracks whose motion differs by more than ``tol`` px from the
        median motion of their (at least two) matched rest neighbours."""
        med, count = self._neighbour_motion(pred, pos, matched)
        return matched & (count >= 2) & (np.hypot(*(pos - pred - med).T) > tol)

    def _grow(self, det: np.ndarray, pred: np.ndarray, of: np.ndarray, tol: float
              ) -> np.ndarray:
        """The tracks' detection rows (-1: none) grown from the matches in ``of`` wave by
        wave at the matched neighbours' motion (:meth:`_waves`, half a spacing around it);
        a match that disagrees with its neighbours at the end is dropped, and the dropped
        tracks get one more round."""
        m = len(self.rest_points)
        of = of.copy()
        matched = of >= 0
        pos = np.full((m, 2), np.nan)
        pos[matched] = det[of[matched]]
        free = np.ones(len(det), dtype=bool)
        free[of[matched]] = False
        for _ in range(2):
            of, pos, matched, free = self._waves(det, pred, of, pos, matched, free,
                                                 0.5 * self.spacing_px,
                                                 4 * int(np.sqrt(m)) + 4)
            off = self._incoherent(pred, pos, matched, tol)
            if not off.any():
                break  # nothing dropped: no track for another round
            matched &= ~off
            free[of[off]] = True
            of[off], pos[off] = -1, np.nan
        return of

    def _assign_regrow(self, det: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Gated assignment, grown again from its coherent patches when it shows aliasing
        (``TrackingParams.regrow``).

        A region of skin moved by about a spacing is matched one marker over by the gated
        assignment: coherent inside, it is bounded by a band where the apparent motion jumps
        by a spacing, with tracks left without a detection at one end and detections left
        unmatched at the other. So when the plain assignment leaves both, or has matches
        that disagree with their rest neighbours (:data:`~perception.params
        .COHERENT_TOLERANCE`), its coherent matches are split into patches (rest neighbours
        whose motions differ by less than the tolerance are joined), and the frame is grown
        again from each patch of at least ``max(3, m // 20)`` markers alone
        (:meth:`_grow`). Grown from the patch that is right, every marker of a smooth field
        is reached (each predicted from its matched neighbours, within half a spacing);
        grown from a patch matched one marker over, the shift carries on until it runs off
        the array and leaves its edge row unmatched. The outcome with the most matches is
        kept, if it has more than the plain assignment's coherent matches; otherwise the
        plain assignment is returned unchanged.
        """
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import connected_components

        from .params import COHERENT_TOLERANCE

        track, match = self._assign(det)
        m = len(self.rest_points)
        if len(det) == 0 or len(track) == 0:
            return track, match
        pred = self.predicted()
        tol = COHERENT_TOLERANCE * self.spacing_px
        of = np.full(m, -1, dtype=np.intp)
        of[track] = match
        matched = of >= 0
        pos = np.full((m, 2), np.nan)
        pos[matched] = det[of[matched]]
        ok = matched & ~self._incoherent(pred, pos, matched, tol)
        if ok.sum() == matched.sum() and (matched.all() or len(match) == len(det)):
            return track, match  # coherent, and nothing left on one side or the other
        nb = self._rest_neighbours()
        nbc = np.maximum(nb, 0)
        motion = pos - pred
        near = np.hypot(*(motion[:, None, :] - motion[nbc]).transpose(2, 0, 1)) <= tol
        r, c = np.nonzero((nb >= 0) & ok[:, None] & ok[nbc] & near)
        _, label = connected_components(coo_matrix((np.ones(len(r)), (r, nbc[r, c])),
                                                   shape=(m, m)), directed=False)
        label = np.where(ok, label, -1)
        sizes = np.bincount(label[ok], minlength=m)
        best, best_n = None, int(ok.sum())
        for k in np.argsort(-sizes, kind="stable"):
            if sizes[k] < max(3, m // 20):
                break
            grown = self._grow(det, pred, np.where(label == k, of, -1), tol)
            n_grown = int((grown >= 0).sum())
            if n_grown > best_n:
                best, best_n = grown, n_grown
                if best_n == min(m, len(det)):
                    break  # every track or every detection matched: nothing can beat it
        if best is None:
            return track, match
        t = np.flatnonzero(best >= 0)
        return t, best[t]

    def _waves(self, det, pred, of, pos, matched, free, step, n_waves):
        """Match the unmatched tracks wave by wave at their matched neighbours' motion."""
        for _ in range(n_waves):
            open_ = np.flatnonzero(~matched)
            med, count = self._neighbour_motion(pred, pos, matched, open_)
            need = 1 if not (count >= 2).any() else 2
            sel = count >= need
            cand = open_[sel]
            fd = np.flatnonzero(free)
            if not len(cand) or not len(fd):
                break
            cost = cdist(pred[cand] + med[sel], det[fd])
            ok = cost <= step
            if not ok.any():
                break
            rows, cols = linear_sum_assignment(np.where(ok, cost, step * (len(cand) + 1.0)))
            take = ok[rows, cols]
            t, d_ = cand[rows[take]], fd[cols[take]]
            of[t], pos[t], matched[t], free[d_] = d_, det[d_], True, False
        return of, pos, matched, free

    def _assign(self, det: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Gated optimal one-to-one assignment: (track indices, detection indices)."""
        if len(det) == 0:
            return np.zeros(0, dtype=np.intp), np.zeros(0, dtype=np.intp)
        from .track_kernels import gated_counts  # compiled on first use (Numba)

        pred = self.predicted()
        lost = ~self._seen  # a lost track may also come back at its rest position
        gate = self.gate_px
        # The optimum decomposes over the connected parts of the gated pairs: a track and a
        # detection that are each other's only candidate (the usual case between frames) are
        # matched directly, and only the tangled rest goes to the assignment solver. The
        # pairs are counted in one compiled pass; cost matrices are built for the rest only.
        row_n, col_n, only = gated_counts(pred, self.rest_points, lost, det, gate)
        r1 = np.flatnonzero((row_n == 1) & (col_n[only] == 1))
        c1 = only[r1]
        rest_r = np.flatnonzero(row_n > 0)
        if len(r1) == len(rest_r):  # every gated pair is isolated
            return r1, c1
        taken_r = np.zeros(len(row_n), dtype=bool)
        taken_r[r1] = True
        taken_c = np.zeros(len(col_n), dtype=bool)
        taken_c[c1] = True
        rest_r = rest_r[~taken_r[rest_r]]
        rest_c = np.flatnonzero((col_n > 0) & ~taken_c)
        sub = cdist(pred[rest_r], det[rest_c])
        back = lost[rest_r]
        if back.any():
            sub[back] = np.minimum(sub[back], cdist(self.rest_points[rest_r[back]], det[rest_c]))
        sub_ok = sub <= gate
        # an infeasible pair costs more than any set of feasible pairs: maximum number of
        # gated matches first, then minimum total distance among those
        big = gate * (min(sub.shape) + 1.0) + 1.0
        rows, cols = linear_sum_assignment(np.where(sub_ok, sub, big))
        accept = sub_ok[rows, cols]
        rows = np.concatenate([r1, rest_r[rows[accept]]])
        cols = np.concatenate([c1, rest_c[cols[accept]]])
        order = np.argsort(rows, kind="stable")
        return rows[order], cols[order]
