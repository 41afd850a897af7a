"""Pictures in the style of the seed paper's Fig. 4.

(a) detections on the frame, (b) the clipped Voronoi tessellation, (c)/(d) the surface
deformation (cell-area change, marker displacement) interpolated over the sensor region with
the centre of pressure as a green spot.

Figures are built with ``matplotlib.figure.Figure`` directly (no ``pyplot``, no GUI backend;
PNGs are written by Agg). matplotlib is imported only when a plotting function is called.
:func:`draw_detections` uses OpenCV only, for quick overlays (the CLI).
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np
import shapely
from scipy.interpolate import griddata
from scipy.spatial import cKDTree

from .detect import MarkerDetection
from .geometry import as_points
from .image import as_grey
from .region import RegionLike, as_polygon
from .voronoi import voronoi_cells

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from .pipeline import FeaturePipeline, FrameFeatures

__all__ = [
    "draw_detections",
    "figure4",
    "interpolate_over_region",
    "plot_deformation_map",
    "plot_detections",
    "plot_features",
    "plot_voronoi",
    "save_figure",
]

_COP_COLOUR = "#00d000"
_REJECT_COLOURS = {"glint": (0, 255, 255), "rim": (0, 128, 255), "size": (0, 0, 255),
                   "shape": (255, 0, 255), "outside": (160, 160, 160)}


def _display(image: np.ndarray) -> np.ndarray:
    """uint8 BGR copy of any accepted image (for drawing)."""
    arr = np.asarray(image)
    if arr.ndim == 3 and arr.shape[2] == 3 and arr.dtype == np.uint8:
        return arr.copy()
    grey = as_grey(arr)
    if grey.dtype != np.uint8:
        grey = np.round(grey * 255.0).astype(np.uint8)
    return cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR)


def draw_detections(image: np.ndarray, detection: MarkerDetection, *,
                    show_rejected: bool = True) -> np.ndarray:
    """Overlay of the detections (OpenCV drawing, no matplotlib).

    Parameters
    ----------
    image : (h, w) or (h, w, 3) array
        The frame that was analysed.
    detection : MarkerDetection
    show_rejected : bool
        Also draw rejected blobs other than tiny specks (glint: yellow, rim: orange, size:
        red, shape: magenta, outside: grey).

    Returns
    -------
    overlay : (h, w, 3) uint8, BGR
        Accepted markers as green circles of the median marker diameter.
    """
    out = _display(image)
    shift = 4
    scale = 1 << shift
    d = detection.marker_diameter_px if np.isfinite(detection.marker_diameter_px) else 8.0
    radius = int(round((0.5 * d + 2.0) * scale))
    for x, y in detection.points:
        cv2.circle(out, (int(round(x * scale)), int(round(y * scale))), radius, (0, 220, 0), 1,
                   cv2.LINE_AA, shift)
    if show_rejected:
        for (x, y), why in zip(detection.rejected_points, detection.rejected_reasons,
                               strict=True):
            colour = _REJECT_COLOURS.get(why)
            if colour is not None:
                cv2.circle(out, (int(round(x * scale)), int(round(y * scale))), radius, colour,
                           1, cv2.LINE_AA, shift)
    return out


def _extent(shape: tuple[int, int]) -> tuple[float, float, float, float]:
    h, w = shape[:2]
    return (-0.5, w - 0.5, h - 0.5, -0.5)  # pixel centres at integer coordinates


def plot_detections(ax: Axes, image: np.ndarray, points: np.ndarray, *,
                    detection: MarkerDetection | None = None, title: str | None = None) -> None:
    """Frame with detected markers (green) and, if ``detection`` is given, rejected blobs.

    Parameters
    ----------
    ax : matplotlib Axes
    image : (h, w) or (h, w, 3) array
    points : (n, 2) float, px, OpenCV (x, y)
    detection : MarkerDetection, optional
    title : str, optional
    """
    disp = _display(image)[:, :, ::-1]
    ax.imshow(disp, extent=_extent(disp.shape), interpolation="nearest")
    pts = as_points(points)
    ax.plot(pts[:, 0], pts[:, 1], "o", ms=4, mfc="none", mec="lime", mew=0.8)
    if detection is not None and len(detection.rejected_points):
        reasons = np.array(detection.rejected_reasons)
        big = reasons != "small"
        rp = detection.rejected_points[big]
        ax.plot(rp[:, 0], rp[:, 1], "x", ms=5, color="red", mew=0.8, label="rejected")
    ax.set_title(title if title is not None else f"(a) {len(pts)} markers")
    ax.set_axis_off()


def plot_voronoi(ax: Axes, points: np.ndarray, region: RegionLike, *,
                 values: np.ndarray | None = None, image: np.ndarray | None = None,
                 cmap: str = "coolwarm", label: str = "cell area change (px²)",
                 title: str | None = None) -> None:
    """Voronoi cells clipped to the region, optionally coloured by a per-marker value.

    Parameters
    ----------
    ax : matplotlib Axes
    points : (m, 2) float, px (NaN rows have no cell)
    region : Polygon, (k, 2) vertices or (h, w) mask
    values : (m,) float, optional
        E.g. area change (px²); symmetric colour limits around 0.
    image : array, optional
        Drawn underneath (greyed).
    cmap : str
    label : str
        Colour-bar label.
    title : str, optional
    """
    from matplotlib.collections import PolyCollection

    poly = as_polygon(region)
    pts = as_points(points)
    cells, _ = voronoi_cells(pts, poly)
    has = np.flatnonzero(~shapely.is_missing(cells))
    parts, which = shapely.get_parts(cells[has], return_index=True)
    keep = (shapely.get_type_id(parts) == 3) & ~shapely.is_empty(parts)  # 3: Polygon
    parts, owner = parts[keep], has[which[keep]]
    coords, ring = shapely.get_coordinates(shapely.get_exterior_ring(parts), return_index=True)
    outlines = np.split(coords, np.flatnonzero(np.diff(ring)) + 1) if len(coords) else []
    if image is not None:
        disp = _display(image)[:, :, ::-1]
        ax.imshow(disp, extent=_extent(disp.shape), alpha=0.5, interpolation="nearest")
    coll = PolyCollection(outlines, edgecolors="k", linewidths=0.4)
    if values is not None:
        v = np.asarray(values, dtype=np.float64)[owner]
        lim = float(np.nanmax(np.abs(v))) if np.isfinite(v).any() else 1.0
        coll.set_array(np.ma.masked_invalid(v))
        coll.set_cmap(cmap)
        coll.set_clim(-lim or -1.0, lim or 1.0)
        ax.figure.colorbar(coll, ax=ax, shrink=0.7, label=label)
    else:
        coll.set_facecolor("none")
    ax.add_collection(coll)
    ax.plot(pts[:, 0], pts[:, 1], ".", ms=2, color="k")
    minx, miny, maxx, maxy = poly.bounds
    ax.set_xlim(minx - 5, maxx + 5)
    ax.set_ylim(maxy + 5, miny - 5)
    ax.set_aspect("equal")
    ax.set_title(title if title is not None else "(b) Voronoi cells clipped to the sensor")
    ax.set_axis_off()


def interpolate_over_region(points: np.ndarray, values: np.ndarray, region: RegionLike,
                            image_shape: tuple[int, int], *, step_px: int = 2
                            ) -> tuple[np.ndarray, tuple[float, float, float, float]]:
    """Interpolate per-marker values over the sensor region.

    Linear interpolation between the markers; the band between the outermost markers and the
    region boundary is filled by adding the boundary itself (sampled every few pixels) as
    extra nodes carrying the value of their nearest marker. NaN outside the region.

    Parameters
    ----------
    points : (m, 2) float, px; NaN rows ignored
    values : (m,) float; NaN entries ignored
    region : Polygon, (k, 2) vertices or (h, w) mask
    image_shape : (h, w)
    step_px : int
        Grid step, px (>= 1).

    Returns
    -------
    grid : (gh, gw) float64
        Interpolated values on pixel centres ``0, step, 2 step, ...``.
    extent : (left, right, bottom, top)
        For ``imshow(grid, extent=extent)`` in pixel coordinates.
    """
    pts = as_points(points)
    v = np.asarray(values, dtype=np.float64)
    ok = np.isfinite(pts).all(axis=1) & np.isfinite(v)
    h, w = image_shape[:2]
    step = max(int(step_px), 1)
    gx, gy = np.meshgrid(np.arange(0, w, step, dtype=np.float64),
                         np.arange(0, h, step, dtype=np.float64))
    grid = np.full(gx.shape, np.nan)
    poly = as_polygon(region)
    inside = shapely.intersects_xy(poly, gx, gy)
    if ok.sum() >= 3:
        boundary = poly.boundary
        ring = shapely.line_interpolate_point(
            boundary, np.arange(0.0, boundary.length, 4.0 * step))
        ghost = shapely.get_coordinates(ring)
        _, nearest = cKDTree(pts[ok]).query(ghost)
        nodes = np.vstack([pts[ok], ghost])
        node_values = np.r_[v[ok], v[ok][nearest]]
        q = np.stack([gx[inside], gy[inside]], axis=1)
        lin = griddata(nodes, node_values, q, method="linear")
        near = griddata(nodes, node_values, q, method="nearest")
        grid[inside] = np.where(np.isfinite(lin), lin, near)
    half = 0.5 * step
    extent = (-half, gx[0, -1] + half, gy[-1, 0] + half, -half)
    return grid, extent


def plot_deformation_map(ax: Axes, points: np.ndarray, values: np.ndarray,
                         region: RegionLike, image_shape: tuple[int, int], *,
                         cop: np.ndarray | None = None, label: str = "",
                         cmap: str = "inferno", symmetric: bool = False,
                         title: str | None = None) -> None:
    """Interpolated deformation over the region with the centre of pressure as a green spot.

    Parameters
    ----------
    ax : matplotlib Axes
    points : (m, 2) float, px
    values : (m,) float
        Per-marker deformation (area change px², displacement px, ...).
    region : Polygon, (k, 2) vertices or (h, w) mask
    image_shape : (h, w)
    cop : (2,) float, px, optional
        Drawn as a green spot when finite.
    label : str
        Colour-bar label.
    cmap : str
    symmetric : bool
        Colour limits symmetric about 0 (for signed values such as area change).
    title : str, optional
    """
    grid, extent = interpolate_over_region(points, values, region, image_shape)
    lim = float(np.nanmax(np.abs(grid))) if np.isfinite(grid).any() else 0.0
    clim = (-lim, lim) if symmetric and lim > 0 else (None, None)
    im = ax.imshow(np.ma.masked_invalid(grid), extent=extent, cmap=cmap,
                   interpolation="bilinear", vmin=clim[0], vmax=clim[1])
    ax.figure.colorbar(im, ax=ax, shrink=0.7, label=label)
    if cop is not None and np.isfinite(cop).all():
        ax.plot([cop[0]], [cop[1]], "o", ms=9, color=_COP_COLOUR, mec="k", mew=0.8)
    minx, miny, maxx, maxy = as_polygon(region).bounds
    ax.set_xlim(minx - 5, maxx + 5)
    ax.set_ylim(maxy + 5, miny - 5)
    ax.set_aspect("equal")
    if title is not None:
        ax.set_title(title)
    ax.set_axis_off()


def plot_features(pipeline: FeaturePipeline, image: np.ndarray, features: FrameFeatures, *,
                  suptitle: str | None = None) -> Figure:
    """Four-panel figure like the seed paper's Fig. 4 for one processed frame.

    Parameters
    ----------
    pipeline : FeaturePipeline
        The pipeline that produced ``features`` (rest positions, region).
    image : array
        The frame.
    features : FrameFeatures
    suptitle : str, optional

    Returns
    -------
    fig : matplotlib.figure.Figure
        (a) detections, (b) clipped Voronoi cells coloured by area change, (c) interpolated
        area change with the area-change CoP (green), (d) interpolated marker displacement
        with the seed CoP (green).
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=(13, 10), dpi=100, layout="constrained")
    axs = fig.subplots(2, 2)
    pts = features.points
    plot_detections(axs[0, 0], image, pts[np.isfinite(pts).all(axis=1)],
                    title=f"(a) {features.n_detected} detected, {features.n_lost} lost")
    plot_voronoi(axs[0, 1], pts, pipeline.region, values=features.growth, image=image)
    plot_deformation_map(axs[1, 0], pts, features.growth, pipeline.region,
                         pipeline.image_shape, cop=features.cop_growth,
                         label="cell area change (px²)", cmap="coolwarm", symmetric=True,
                         title="(c) area change, CoP weighted by growth")
    disp = np.hypot(*(pts - pipeline.rest_points).T)
    plot_deformation_map(axs[1, 1], pts, disp, pipeline.region, pipeline.image_shape,
                         cop=features.cop_area, label="marker displacement (px)",
                         title="(d) displacement, CoP weighted by area (seed)")
    if suptitle:
        fig.suptitle(suptitle)
    return fig


def figure4(
    image: np.ndarray | str | PathLike[str],
    *,
    rest_image: np.ndarray | str | PathLike[str] | None = None,
    expected_count: int | None = None,
    region: RegionLike | None = None,
    out_path: str | PathLike[str] | None = None,
    title: str | None = None,
    dpi: int = 100,
) -> Figure:
    """Fig. 4-style picture of one frame, from an image (path) alone or against a rest frame.

    Parameters
    ----------
    image : array or path
        The frame.
    rest_image : array or path, optional
        With a rest frame: the four panels of :func:`plot_features` (area change and
        displacement against rest). Without: (a) detections, (b) clipped Voronoi cells
        coloured by area, (c) interpolated cell area with the seed CoP as a green spot
        (cells grow where the skin is indented, so the area map alone shows the contact).
    expected_count : int, optional
        Passed to the detector.
    region : Polygon, (k, 2) vertices or (h, w) mask, optional
        Sensor region; default: fitted to the detected markers.
    out_path : path, optional
        Also write the figure there as PNG.
    title : str, optional
    dpi : int

    Returns
    -------
    fig : matplotlib.figure.Figure
    """
    from matplotlib.figure import Figure

    from .cop import centre_of_pressure
    from .detect import detect_markers_detailed
    from .image import read_image
    from .pipeline import FeaturePipeline
    from .region import fit_region
    from .voronoi import voronoi_areas

    frame = read_image(image) if isinstance(image, str | PathLike) else np.asarray(image)
    if rest_image is not None:
        pipe = FeaturePipeline(rest_image, expected_count=expected_count, region=region)
        fig = plot_features(pipe, frame, pipe.process(frame), suptitle=title)
    else:
        det = detect_markers_detailed(frame, expected_count=expected_count, mask=region)
        poly = as_polygon(region, image_shape=det.image_shape) if region is not None else (
            fit_region(det.points) if det.count >= 3 else None)
        fig = Figure(figsize=(16, 5), dpi=dpi, layout="constrained")
        axs = fig.subplots(1, 3)
        plot_detections(axs[0], frame, det.points, detection=det,
                        title=f"(a) {det.count} markers"
                              + ("" if det.reliable else f" (unreliable: {det.reason})"))
        if poly is not None:
            areas = voronoi_areas(det.points, poly)
            plot_voronoi(axs[1], det.points, poly, values=areas - np.median(areas),
                         image=frame, label="cell area - median cell area (px²)",
                         title="(b) Voronoi cells clipped to the sensor")
            plot_deformation_map(axs[2], det.points, areas, poly, det.image_shape,
                                 cop=centre_of_pressure(det.points, areas),
                                 label="cell area (px²)",
                                 title="(c) cell area, CoP weighted by area (seed)")
        else:
            for ax in axs[1:]:
                ax.set_axis_off()
        if title:
            fig.suptitle(title)
    if out_path is not None:
        save_figure(fig, out_path, dpi=dpi)
    return fig


def save_figure(fig: Figure, path: str | PathLike[str], *, dpi: int = 100) -> Path:
    """Write a figure as PNG (Agg), creating the folder; returns the path."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=dpi, format="png")
    return out
