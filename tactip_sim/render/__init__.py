"""Rendering: the Mitsuba 3 fisheye sensor plugin, the fingertip scene, the camera model and
frames with their analytic ground truth. Mitsuba loads on the first render, not on import."""

from .centroids import blob_centroids, match_blobs
from .frame import Frame
from .noise import CameraModel
from .renderer import Renderer

__all__ = ["CameraModel", "Frame", "Renderer", "blob_centroids", "match_blobs"]
