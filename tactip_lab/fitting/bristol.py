"""Labelled TacTip data sets in the Bristol layout, real or simulated.

A Bristol-layout folder holds ``targets.csv`` (one row per frame: an image column and the pose
columns ``pose_1 … pose_6`` = x, y, z in mm and Rx, Ry, Rz in degrees) and the images it names,
either beside it or in ``images/``. The Bristol tactile data sets (Tactile Gym, the lab's pose
data sets) use ``sensor_image`` for the image column; this project's own datasets use ``image``
and add ``images/rest.png``, their perceived features and a ``manifest.json``.

Mapping (documented defaults, each a command-line option):

=============  ===============  =============================================================
quantity        column           note
=============  ===============  =============================================================
roll (deg)      ``pose_4``       Rx; ``--roll-column``, ``--roll-sign -1`` to flip
pitch (deg)     ``pose_5``       Ry; ``--pitch-column``, ``--pitch-sign``
depth (mm)      ``pose_3``       z, only used to choose the reference frame
image           ``sensor_image`` else ``image``; ``--image-column``
=============  ===============  =============================================================

A folder without ``targets.csv`` may hold a plain ``labels.csv`` instead; a default column
the file lacks is looked for under its descriptive names (:data:`COLUMN_ALIASES`: e.g.
``roll_deg_Rx``, ``pitch_deg_Ry``, ``depth_mm``).

Reference (rest) frame: ``--rest IMAGE`` if given; else the folder's ``images/rest.png`` (this
project's datasets); else, when the folder has a depth column that varies, the *least
deformed* frame: a row of depth <= 0 (a frame without contact) if there is one, else the
pixel-wise median of the ``round(sqrt(N))`` shallowest presses (:func:`median_reference`; only
presses within :data:`MEDIAN_DEPTH_SPAN` of the depth range of the shallowest, and at least
:data:`MEDIAN_MIN_FRAMES` of them, else the shallowest press alone); without a depth column,
the first frame. The choice is recorded in every output.

Why a median: a data set of taps without a rest frame has no frame without contact, and its
shallowest tap is tilted like any other (the real 128x128 set's, ``image_501``, is 2.0 mm deep
at Rx 11.0 deg, Ry 8.1 deg). Every CoP is measured against the reference, so its tilt biases
every feature the same way. Taps at random angles tilt each way alike: the pixel-wise median
of the shallowest ones keeps each marker near its middle position, a reference with the
tilts averaged out and the depth of the shallowest taps. docs/real_data.md measures it.

Each frame is perceived on its own against the reference (tracking from the reference's markers,
as for a tap), so the order of the rows does not matter. Tracking straight from the reference to
a deep tap must accept larger jumps than frame-to-frame tracking does: the gate is
:data:`TAP_GATE_FRACTION` of the marker spacing (the assignment stays one-to-one).
"""

from __future__ import annotations

import csv
import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from tactip_lab.fitting.fit import (
    DEFAULT_FEATURE,
    FEATURES,
    FOLDER_FEATURES,
    FeatureTable,
    check_feature,
    make_model,
)
from tactip_lab.sampling.dataset import DATASET_KIND, MANIFEST, DatasetError

TAP_GATE_FRACTION = 1.0
"""Tracking gate for taps, as a fraction of the rest spacing (frame-to-frame sequences use 0.5,
:class:`perception.TrackingParams`). On the 1 000 real 128x128 taps of ``../shared/real`` the
frames flagged for lost tracks went from 363 (gate 0.5) to 12 (docs/real_data.md)."""
TAP_SEARCH_FRACTION = 0.5
"""How far beyond the Voronoi region (the rest markers' hull grown by half a spacing) taps are
searched for markers, as a fraction of the rest spacing: half a spacing, so that the search
reaches one tracking gate (:data:`TAP_GATE_FRACTION` spacings) beyond the hull and a rim marker
that a tilted press pushes outward is found as far as it can be tracked
(:class:`perception.FeaturePipeline` ``search_margin_px``)."""

IMAGE_COLUMNS = ("sensor_image", "image")
"""Image columns looked for, in this order (Bristol data sets, then this project's)."""
LABEL_FILES = ("targets.csv", "labels.csv")
"""Label files looked for, in this order: the Bristol layout's, then a plain ``labels.csv``
(e.g. ``../shared/real/tactip331_tap``: ``image, depth_mm, roll_deg_Rx, pitch_deg_Ry``)."""
COLUMN_ALIASES = {
    "roll": ("pose_4", "roll_deg_Rx", "roll_deg", "Rx"),
    "pitch": ("pose_5", "pitch_deg_Ry", "pitch_deg", "Ry"),
    "depth": ("pose_3", "depth_mm"),
}
"""Where a column left at its default (``pose_4``, ``pose_5``, ``pose_3``) is absent, the
first of these names the file has is taken (and recorded in ``BristolFolder.columns``): the
descriptive names of a plain label file. A column given on the command line is never
replaced."""


@dataclass(frozen=True)
class ColumnMap:
    """Which columns hold the angles (and the depth), and their signs."""

    roll: str = "pose_4"
    pitch: str = "pose_5"
    depth: str | None = "pose_3"
    roll_sign: float = 1.0
    pitch_sign: float = 1.0
    image: str | None = None  # None: the first of IMAGE_COLUMNS present

    def __post_init__(self) -> None:
        for name in ("roll_sign", "pitch_sign"):
            if getattr(self, name) not in (1.0, -1.0):
                raise ValueError(f"{name}={getattr(self, name)!r} is not allowed: 1 or -1")


@dataclass(frozen=True)
class BristolFolder:
    """A labelled folder: its images and angles (rows in file order).

    images : one path per row
    angles_deg : (n, 2) roll, pitch (degrees, signs applied)
    depth_mm : (n,) the depth column (NaN when the folder has none)
    rest : the reference frame's path, and ``rest_choice`` how it was chosen; for a median
        reference, the shallowest of the frames it was made from
    ours : True for this project's own datasets (their perceived features are in the table)
    rest_frame : the reference image when it is not a file (a median reference), else None
    """

    root: Path
    columns: ColumnMap
    images: list[Path]
    angles_deg: np.ndarray
    depth_mm: np.ndarray
    rest: Path
    rest_choice: str
    ours: bool
    table: dict[str, list[str]] = field(repr=False)
    rest_frame: np.ndarray | None = field(default=None, repr=False, compare=False)

    @classmethod
    def open(cls, root: str | Path, *, columns: ColumnMap | None = None,
             rest: str | Path | None = None) -> BristolFolder:
        """Read ``root``'s ``targets.csv`` and check its images.

        Raises
        ------
        DatasetError
            No ``targets.csv``, a missing column, an image that is missing, unreadable or of
            another size than the others, or a rest frame of another size (each message names
            the file and the problem).
        """
        import cv2

        columns = columns or ColumnMap()
        root = Path(root)
        path = next((root / f for f in LABEL_FILES if (root / f).is_file()), None)
        if path is None:
            raise DatasetError(f"{root}: no targets.csv (a Bristol-layout folder holds "
                               "targets.csv and the images it names; a plain labels.csv "
                               "is read too)")
        try:  # utf-8-sig: a byte-order mark before the header (a spreadsheet's export) is read
            with path.open(newline="", encoding="utf-8-sig") as fh:
                reader = csv.DictReader(fh)
                header = reader.fieldnames or []
                rows = list(reader)
        except UnicodeDecodeError as exc:
            raise DatasetError(f"{path}: not a text (CSV) file: byte {exc.start} is not UTF-8 "
                               "(a binary file, or another encoding: save it as UTF-8)") from None
        except csv.Error as exc:
            raise DatasetError(f"{path}: not a readable CSV file ({exc})") from None
        columns = _aliased(columns, header)
        if not rows:
            raise DatasetError(f"{path}: no rows")
        for i, r in enumerate(rows):  # DictReader: None for a short row's missing cells,
            extra = r.pop(None, None) or []  # and the key None for a long row's extra ones
            n = sum(v is not None for v in r.values()) + len(extra)
            if n != len(header):
                raise DatasetError(f"{path}: data row {i + 1} has {n} fields but the header has "
                                   f"{len(header)} (a truncated or torn file?)")
        image_col = columns.image or next((c for c in IMAGE_COLUMNS if c in header), None)
        if image_col is None or image_col not in header:
            raise DatasetError(f"{path}: no image column (looked for "
                               f"{columns.image or ' or '.join(IMAGE_COLUMNS)}; columns: "
                               f"{', '.join(header)}); give it with --image-column")
        for opt, col in (("--roll-column", columns.roll), ("--pitch-column", columns.pitch)):
            if col not in header:
                raise DatasetError(f"{path}: no column {col!r} ({opt}); columns: "
                                   f"{', '.join(header)}")
        table = {c: [r[c] for r in rows] for c in header}
        _check_unique_rows(table[image_col], path)
        images = [_find_image(root, name, path, i) for i, name in enumerate(table[image_col])]
        angles = np.stack([_angles(table[columns.roll], path, columns.roll) * columns.roll_sign,
                           _angles(table[columns.pitch], path, columns.pitch)
                           * columns.pitch_sign], axis=1)
        depth = (_finite(_floats(table[columns.depth], path, columns.depth), path,
                         f"depth column {columns.depth!r} (--depth-column)",
                         "it chooses the reference frame")
                 if columns.depth and columns.depth in header else np.full(len(rows), np.nan))
        sizes = {}
        for p in images:
            head = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
            if head is None:
                raise DatasetError(f"{p}: not a readable image")
            sizes.setdefault(head.shape[:2], p)
        if len(sizes) > 1:
            (s0, p0), (s1, p1) = list(sizes.items())[:2]
            raise DatasetError(f"{root}: images of different sizes ({p0.name} is "
                               f"{s0[1]}x{s0[0]}, {p1.name} is {s1[1]}x{s1[0]}); one folder "
                               "must hold one camera format")
        ours = _is_ours(root)
        rest_path, choice, frame = _choose_rest(root, rest, images, depth, ours)
        ref = cv2.imread(str(rest_path), cv2.IMREAD_UNCHANGED)
        if ref is None:
            raise DatasetError(f"{rest_path}: the rest frame is not a readable image")
        (size,) = sizes
        if ref.shape[:2] != size:
            raise DatasetError(f"{rest_path}: the rest frame is {ref.shape[1]}x{ref.shape[0]} "
                               f"but the folder's frames are {size[1]}x{size[0]}: a rest frame "
                               "of another sensor or format")
        return cls(root, columns, images, angles, depth, rest_path, choice, ours, table, frame)

    @property
    def reference(self) -> np.ndarray | str:
        """The reference frame as perception takes it: the median image, or the file's path."""
        return self.rest_frame if self.rest_frame is not None else str(self.rest)

    @property
    def reference_is_a_press(self) -> bool:
        """Whether the reference is a press (the shallowest, or the median of the shallowest
        few), not a frame without contact: the folder has no rest frame."""
        return self.rest_choice.startswith(LEAST_DEFORMED)

    def with_single_rest(self, why: str) -> BristolFolder:
        """This folder with its shallowest press alone as the reference (a median reference
        that perception cannot use: ``why``)."""
        from dataclasses import replace

        return replace(self, rest_frame=None, rest_choice=(
            f"{LEAST_DEFORMED}: the shallowest press ({self.rest.name}); {why}"))

    @property
    def image_size(self) -> tuple[int, int]:
        import cv2

        h, w = cv2.imread(str(self.images[0]), cv2.IMREAD_UNCHANGED).shape[:2]
        return int(w), int(h)

    def __len__(self) -> int:
        return len(self.images)


def _aliased(columns: ColumnMap, header: Sequence[str]) -> ColumnMap:
    """``columns`` with each quantity left at its default column, where the file lacks that
    column, moved to the first of its :data:`COLUMN_ALIASES` the file has."""
    from dataclasses import replace

    default = ColumnMap()
    moved = {}
    for key, names in COLUMN_ALIASES.items():
        col = getattr(columns, key)
        if col == getattr(default, key) and col not in header:
            found = next((n for n in names if n in header), None)
            if found is not None:
                moved[key] = found
    return replace(columns, **moved) if moved else columns


def _floats(values: Sequence[str], path: Path, col: str) -> np.ndarray:
    try:
        return np.array([float(v) for v in values])
    except ValueError as exc:
        raise DatasetError(f"{path}: column {col!r} is not numeric ({exc})") from None


ANGLE_LIMIT_DEG = 90.0
"""Roll and pitch labels must lie in (-90, 90) degrees: a pad tilted 90 degrees or more to a
surface does not press it (the simulator's own poses have the same range,
:class:`tactip_sim.fem.Pose`). The real data sets span +-15 degrees."""


def _rows(bad: np.ndarray) -> str:
    """'row 3', 'rows 3, 7 and 9', 'rows 3, 7, 9 ... (12 rows)' (1-based data rows)."""
    idx = [int(i) + 1 for i in np.flatnonzero(bad)]
    if len(idx) == 1:
        return f"row {idx[0]}"
    shown = ", ".join(str(i) for i in idx[:5])
    return (f"rows {shown}" + (f" ... ({len(idx)} rows)" if len(idx) > 5 else "")
            if len(idx) > 2 else f"rows {idx[0]} and {idx[1]}")


def _finite(values: np.ndarray, path: Path, what: str, why: str) -> np.ndarray:
    bad = ~np.isfinite(values)
    if bad.any():
        raise DatasetError(f"{path}: {what} is not finite in {_rows(bad)} (e.g. "
                           f"{values[bad][0]!r}); {why}: fix or remove those rows")
    return values


def _angles(values: Sequence[str], path: Path, col: str) -> np.ndarray:
    """A roll or pitch column: finite, in (-90, 90) degrees (:data:`ANGLE_LIMIT_DEG`)."""
    a = _finite(_floats(values, path, col), path, f"column {col!r}",
                "an angle label must be a number")
    bad = np.abs(a) >= ANGLE_LIMIT_DEG
    if bad.any():
        raise DatasetError(f"{path}: column {col!r} holds {a[bad][0]:g} degrees in "
                           f"{_rows(bad)}, outside the physical range (-90, 90) of a roll or "
                           "pitch label (radians? another column? give the angle columns with "
                           "--roll-column/--pitch-column)")
    return a


def _check_unique_rows(names: Sequence[str], path: Path) -> None:
    """Each image once: a duplicated row (or an image labelled twice) would sit in two
    cross-validation folds, training and testing on the same frame."""
    first: dict[str, int] = {}
    for i, name in enumerate(names):
        if name in first:
            raise DatasetError(f"{path}: {name} is named in rows {first[name] + 1} and {i + 1} "
                               "(a duplicated row?): one frame in two rows would be used twice "
                               "and leak across cross-validation folds; remove the copy")
        first[name] = i


def _find_image(root: Path, name: str, path: Path, row: int) -> Path:
    for cand in (root / name, root / "images" / name):
        if cand.is_file():
            return cand
    raise DatasetError(f"{path}: row {row + 1} names {name!r}, which is neither in {root} nor in "
                       f"{root / 'images'}")


def _is_ours(root: Path) -> bool:
    m = root / MANIFEST
    if not m.is_file():
        return False
    try:
        return json.loads(m.read_text()).get("kind") == DATASET_KIND
    except (OSError, ValueError):
        return False


LEAST_DEFORMED = "least deformed"
"""How :attr:`BristolFolder.rest_choice` begins when the reference is a press (the folder has
no frame without contact): :attr:`BristolFolder.reference_is_a_press`."""
MEDIAN_MIN_FRAMES = 5
"""A median reference needs at least this many presses (``round(sqrt(N)) >= 5``, N >= 21
frames, all within :data:`MEDIAN_DEPTH_SPAN`); with fewer, the shallowest press alone is the
reference."""
MEDIAN_DEPTH_SPAN = 0.1
"""A median reference takes only presses within this fraction of the folder's depth range of
the shallowest one: it averages the tilts of the least deformed frames, not deeper ones."""


def median_reference(paths: Sequence[Path]) -> np.ndarray:
    """The pixel-wise median of the frames ``paths`` (one format), in their dtype and channels.
    Frames that all hold the same two levels (binarised) give a two-level median: a pixel
    takes the level most of the frames give it (ties, possible for an even count, go to the
    bright level)."""
    import cv2

    stack = np.stack([cv2.imread(str(p), cv2.IMREAD_UNCHANGED) for p in paths])
    levels = np.unique(stack[: min(len(stack), 3)])
    if len(levels) == 2 and np.isin(stack, levels).all():
        lo, hi = levels
        bright = 2 * np.count_nonzero(stack == hi, axis=0) >= len(stack)
        return np.where(bright, hi, lo).astype(stack.dtype)
    return np.rint(np.median(stack, axis=0)).astype(stack.dtype)


def _choose_rest(root: Path, rest: str | Path | None, images: list[Path], depth: np.ndarray,
                 ours: bool) -> tuple[Path, str, np.ndarray | None]:
    if rest is not None:
        p = Path(rest)
        if not p.is_file():
            raise DatasetError(f"--rest {rest}: no such image")
        return p, "given (--rest)", None
    own = root / "images" / "rest.png"
    if own.is_file():
        return own, "the folder's images/rest.png", None
    if np.all(np.isfinite(depth)) and np.ptp(depth) > 0:
        order = np.argsort(depth, kind="stable")
        k = int(order[0])
        shallow = int(np.count_nonzero(depth <= depth[k] + MEDIAN_DEPTH_SPAN * np.ptp(depth)))
        n = min(int(round(np.sqrt(len(images)))), shallow)
        if depth[k] <= 0.0:
            return images[k], (f"a frame without contact (depth {depth[k]:g}: "
                               f"{images[k].name})"), None
        if n < MEDIAN_MIN_FRAMES:
            return images[k], f"{LEAST_DEFORMED}: the shallowest press ({images[k].name})", None
        picked = [images[int(i)] for i in order[:n]]
        return images[k], (
            f"{LEAST_DEFORMED}: the pixel-wise median of the {n} shallowest presses (depth "
            f"{depth[order[0]]:.4g}-{depth[order[n - 1]]:.4g}; {images[k].name} the "
            "shallowest)"), median_reference(picked)
    return images[0], f"the first frame ({images[0].name}; no depth column varies)", None


# ---------------------------------------------------------------------------------------------
# Features of every frame

def _flow_names() -> tuple[str, ...]:
    from perception.flow import FLOW_NAMES

    return FLOW_NAMES


PER_FRAME_COLUMNS = ("index", "image", "roll_deg", "pitch_deg", "depth_mm", *(
    f"cop_{f}_{a}_px" for f in FEATURES for a in "xy"), *(f"flow_{n}" for n in _flow_names()),
    "n_detected", "n_tracked", "reliable", "reason")


@dataclass(frozen=True)
class FrameTable:
    """Per-frame features of a folder.

    cop : {feature name: (n, 2) px, or (n, d) for a vector feature} (NaN where undefined;
    the vector features only when perceived from the frames)
    reliable : (n,) bool, the pipeline's verdict; reason : why not
    n_tracked : (n,) markers of the reference tracked in each frame (None: stored features)
    """

    folder: BristolFolder
    cop: dict[str, np.ndarray]
    n_detected: np.ndarray
    reliable: np.ndarray
    reason: list[str]
    rest_markers: int | None  # markers on the reference frame (None: stored features)
    detection_reliable: np.ndarray | None = None  # (n,) bool; None: as ``reliable``
    n_tracked: np.ndarray | None = None

    def usable(self, feature: str) -> np.ndarray:
        """(n,) bool: frames whose verdict allows ``feature``: the lab's ``hull`` CoP needs
        only a reliable detection (it is computed on the frame's detected markers, without
        tracking), the others the full verdict (tracking included)."""
        if feature == "hull" and self.detection_reliable is not None:
            return self.detection_reliable
        return self.reliable

    def features(self, feature: str = DEFAULT_FEATURE, *, keep_flagged: bool = False
                 ) -> FeatureTable:
        """The rows usable for fitting or scoring: a finite feature, and reliable unless
        ``keep_flagged``."""
        check_feature(feature, allowed=FOLDER_FEATURES)
        if feature not in self.cop:
            raise DatasetError(f"{self.folder.root}: the {feature!r} feature is perceived from "
                               "the frames; this project's datasets store only the CoP features "
                               f"({', '.join(FEATURES)}): pass --perceive")
        cop = self.cop[feature]
        ok = np.all(np.isfinite(cop), axis=1) & (self.usable(feature) | keep_flagged)
        f = self.folder
        return FeatureTable(cop[ok], f.angles_deg[ok], f.depth_mm[ok], np.flatnonzero(~ok),
                            f.image_size)

    def write_csv(self, path: str | Path) -> None:
        from tactip_lab.sampling.dataset import atomic_write_text

        lines = [",".join(PER_FRAME_COLUMNS)]
        f = self.folder
        for i in range(len(f)):
            cells = [str(i), f.images[i].name, repr(float(f.angles_deg[i, 0])),
                     repr(float(f.angles_deg[i, 1])), repr(float(f.depth_mm[i]))]
            cells += [repr(float(self.cop[name][i, k])) for name in FEATURES for k in (0, 1)]
            flow = self.cop.get("flow", np.full((len(f), len(_flow_names())), np.nan))
            cells += [repr(float(v)) for v in flow[i]]
            tracked = "" if self.n_tracked is None else str(int(self.n_tracked[i]))
            cells += [str(int(self.n_detected[i])), tracked, str(int(self.reliable[i])),
                      '"' + self.reason[i].replace('"', "'") + '"']
            lines.append(",".join(cells))
        atomic_write_text(Path(path), "\n".join(lines) + "\n")

    def summary(self) -> dict[str, Any]:
        return {"frames": len(self.folder), "flagged": int((~self.reliable).sum()),
                "rest": str(self.folder.rest), "rest_choice": self.folder.rest_choice,
                "rest_markers": self.rest_markers,
                "image_size": list(self.folder.image_size),
                "columns": {k: getattr(self.folder.columns, k) for k in
                            ("image", "roll", "pitch", "depth", "roll_sign", "pitch_sign")}}


OTHER_SENSOR_CHECK_FRAMES = 5
"""The reference frame's marker count is compared with the median count of this many first
frames (:func:`_check_same_sensor`)."""
OTHER_SENSOR_RATIO = 1.25
"""A reference frame with more than this many times (or fewer than 1/this) the markers the
folder's frames show is taken for another sensor's. A press hides or merges at most a few
markers at the rim (e.g. 328-334 of 331 on the 1 000 real 128x128 taps, docs/real_data.md);
the two Bristol TacTips differ by a factor 331/127 = 2.6."""


def _check_same_sensor(folder: BristolFolder, rest_markers: int) -> None:
    """The markers detected on the whole of the first frames (not only within the reference's
    region, where the pipeline looks) must number about as many as on the reference frame."""
    import perception as pc

    counts = []
    for path in folder.images[:OTHER_SENSOR_CHECK_FRAMES]:
        try:
            counts.append(len(pc.detect_markers(str(path))))
        except pc.PerceptionError:
            continue  # such a frame is flagged by the pipeline with its reason
    if not counts:
        return
    med = float(np.median(counts))
    ratio = med / max(rest_markers, 1)
    if not 1 / OTHER_SENSOR_RATIO <= ratio <= OTHER_SENSOR_RATIO:
        raise DatasetError(
            f"{folder.rest}: the reference frame shows {rest_markers} markers but the folder's "
            f"first frames a median of {med:g} (ratio {ratio:.2f}, allowed "
            f"{1 / OTHER_SENSOR_RATIO:.2f}-{OTHER_SENSOR_RATIO:.2f}): a rest frame of another "
            "sensor? Pass --rest with a rest frame of this sensor")


def tap_pipeline(reference: np.ndarray | str, expected_count: int | None = None):
    """The feature pipeline a folder of taps is perceived with: each frame tracked straight
    from ``reference`` (no velocity) with a gate of :data:`TAP_GATE_FRACTION` spacings, an
    oversized blob a merged pair only if a marker is missing next to it, the search
    reaching :data:`TAP_SEARCH_FRACTION` spacings beyond the Voronoi region, and an
    assignment that shows aliasing (part of the skin moved by about a spacing and matched one
    marker over) grown again from its coherent patches (``TrackingParams(regrow=True)``; a
    deep or tilted tap moves the skin by up to 1.4 spacings against the shallowest press,
    docs/perception.md)."""
    import perception as pc

    tracking = pc.TrackingParams(gate_fraction=TAP_GATE_FRACTION, use_velocity=False,
                                 merge_needs_lost_neighbour=True, regrow=True)
    pipe = pc.FeaturePipeline(reference, expected_count=expected_count, tracking=tracking)
    if TAP_SEARCH_FRACTION > 0:  # the spacing is known once the rest frame is detected
        pipe = pc.FeaturePipeline(reference, expected_count=expected_count, tracking=tracking,
                                  search_margin_px=TAP_SEARCH_FRACTION * pipe.spacing_px)
    return pipe


def perceive_folder(folder: BristolFolder, *, expected_count: int | None = None,
                    progress: bool = False) -> FrameTable:
    """Every frame of ``folder`` through the feature pipeline, each against the reference.

    Raises
    ------
    DatasetError
        The reference frame cannot be perceived (the message says why).
    """
    from tqdm import tqdm

    import perception as pc

    try:
        try:
            pipe = tap_pipeline(folder.reference, expected_count)
        except pc.PerceptionError as exc:
            if folder.rest_frame is None:
                raise
            folder = folder.with_single_rest(f"their median was not usable ({exc})")
            pipe = tap_pipeline(folder.reference, expected_count)
    except pc.PerceptionError as exc:
        raise DatasetError(f"{folder.rest}: the reference frame cannot be used ({exc})") from None
    _check_same_sensor(folder, len(pipe.rest_points))
    n = len(folder)
    cop = {name: np.full((n, 2), np.nan) for name in FEATURES}
    cop["flow"] = np.full((n, len(_flow_names())), np.nan)
    detected = np.zeros(n, dtype=np.int64)
    tracked = np.zeros(n, dtype=np.int64)
    reliable = np.zeros(n, dtype=bool)
    detection_ok = np.zeros(n, dtype=bool)
    reasons = [""] * n
    for i, path in enumerate(tqdm(folder.images, disable=not progress, unit="frame",
                                  desc=folder.root.name, dynamic_ncols=True)):
        pipe.reset()
        try:
            f = pipe.process(str(path))
        except pc.PerceptionError as exc:
            reasons[i] = f"not perceived: {exc}"
            continue
        cop["area"][i] = f.cop_area
        cop["growth"][i] = f.cop_growth
        cop["hull"][i] = f.cop_hull
        cop["flow"][i] = f.flow
        detected[i] = f.n_detected
        tracked[i] = len(f.points) - f.n_lost
        reliable[i] = bool(f.reliable)
        detection_ok[i] = bool(f.detection_reliable)
        reasons[i] = "" if f.reliable else f.reason
    return FrameTable(folder, cop, detected, reliable, reasons, len(pipe.rest_points),
                      detection_ok, tracked)


def stored_features(folder: BristolFolder) -> FrameTable:
    """This project's own dataset: the features its sweep perceived (averaged over the frames
    of each sample) instead of re-perceiving the one frame it saved per sample."""
    from tactip_lab.sampling.dataset import Dataset

    t = Dataset(folder.root).table()
    cop = {name: np.stack([t[f"cop_{name}_x_px"], t[f"cop_{name}_y_px"]], axis=1)
           for name in FEATURES}
    # a sample's stored CoP averages the frames where it was defined: every finite one counts
    n = len(t["index"])
    return FrameTable(folder, cop, np.asarray(t["n_markers"]), np.ones(n, dtype=bool),
                      [""] * n, None)


def folder_features(folder: BristolFolder, *, perceive: bool = False,
                    expected_count: int | None = None, progress: bool = False) -> FrameTable:
    """Features of a folder: stored ones for this project's datasets (unless ``perceive``),
    perceived from the images otherwise."""
    if folder.ours and not perceive:
        return stored_features(folder)
    return perceive_folder(folder, expected_count=expected_count, progress=progress)


def cross_validate(table: FeatureTable, order: int, folds: int, *, seed: int = 0,
                   feature: str = DEFAULT_FEATURE) -> dict[str, Any]:
    """``folds``-fold cross-validated R² of an order-``order`` regressor of ``feature``: every
    sample predicted by the model fitted without its fold (shuffled folds, seeded), R² over all
    predictions."""
    n = len(table.cop_px)
    if n < 2:
        raise ValueError(f"{n} usable frames (with a reliable CoP): cross-validation needs at "
                         "least 2 (are the frames those of this sensor? see `tactip features`)")
    if folds < 2 or folds > n:
        raise ValueError(f"--cv={folds} is out of range: allowed [2, {n}] (the usable frames; "
                         "without --cv, the choice of feature and order uses 5 folds)")
    idx = np.random.default_rng(seed).permutation(n)
    pred = np.full((n, 2), np.nan)
    for k in range(folds):
        test = idx[k::folds]
        train = np.setdiff1d(idx, test)
        model = make_model(order, feature, table.image_size)
        model.fit(table.cop_px[train], table.angles_deg[train])
        pred[test] = model.predict(table.cop_px[test])
    y = table.angles_deg
    r2 = 1.0 - ((y - pred) ** 2).sum(axis=0) / ((y - y.mean(axis=0)) ** 2).sum(axis=0)
    rmse = np.sqrt(((y - pred) ** 2).mean(axis=0))
    return {"folds": folds, "order": order, "seed": seed, "r2_roll": float(r2[0]),
            "r2_pitch": float(r2[1]), "rmse_roll_deg": float(rmse[0]),
            "rmse_pitch_deg": float(rmse[1]), "predicted_deg": pred}


__all__ = ["IMAGE_COLUMNS", "PER_FRAME_COLUMNS", "BristolFolder", "ColumnMap", "FrameTable",
           "cross_validate", "folder_features", "perceive_folder", "stored_features"]
