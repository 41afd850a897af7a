"""What a map produces: :class:`Panel` (one coloured grid with its failure mask and
boundary) and :class:`MapResult` (a map's panels, timing and findings), and the JSON helpers
behind their summaries.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tactip_lab.sampling.dataset import plain

# ---------------------------------------------------------------------------------------------
# Results

@dataclass
class Panel:
    """One coloured grid of a map with its failure mask.

    values : (ny, nx) the metric; fail : (ny, nx) bool; x/y : axis values or labels
    """

    title: str
    x_label: str
    x: list[Any]
    y_label: str
    y: list[Any]
    metric: str
    unit: str
    values: np.ndarray
    fail: np.ndarray
    threshold: float | None
    failure: str
    x_ref: Any = None  # the nominal x (boundaries are measured from it)
    log_colour: bool = False
    notes: np.ndarray | None = None  # (ny, nx) short strings shown in failing cells
    extra: dict[str, Any] = field(default_factory=dict)
    overlays: list[dict[str, Any]] = field(default_factory=list)

    def boundary(self) -> list[dict[str, Any]]:
        """Per row: the contiguous passing run around ``x_ref`` and the first failing x on
        either side (None: no failure in the grid on that side)."""
        return [{"y": _plain(y), **_row_boundary(self.x, self.fail[i], self.x_ref)}
                for i, y in enumerate(self.y)]

    def summary(self) -> dict[str, Any]:
        return {
            "title": self.title, "x": {"name": self.x_label, "values": _plain(self.x)},
            "y": {"name": self.y_label, "values": _plain(self.y)},
            "metric": {"name": self.metric, "unit": self.unit,
                       "values": _plain(self.values)},
            "threshold": self.threshold, "failure": self.failure,
            "fail": self.fail.astype(bool).tolist(), "boundary": self.boundary(),
            "failing_cells": int(self.fail.sum()), "cells": int(self.fail.size),
            **({"notes": self.notes.tolist()} if self.notes is not None else {}),
            **_plain(self.extra),
        }


@dataclass
class MapResult:
    name: str
    title: str
    what: str  # one or two lines for the report
    panels: list[Panel]
    seconds: float = 0.0
    extra: dict[str, Any] = field(default_factory=dict)
    findings: list[str] = field(default_factory=list)

    def summary(self) -> dict[str, Any]:
        return {"title": self.title, "what": self.what, "png": f"{self.name}.png",
                "panels": [p.summary() for p in self.panels],
                "boundary": self.panels[0].boundary(), "findings": self.findings,
                "seconds": round(self.seconds, 2), **_plain(self.extra)}


def _row_boundary(xs: Sequence[Any], fail: np.ndarray, x_ref: Any) -> dict[str, Any]:
    """The contiguous passing run around ``x_ref``, the first failing x on either side of it
    (None: none in the grid) and every passing run ([first, last] x)."""
    fail = np.asarray(fail, dtype=bool)
    runs, start = [], None
    for k, f in enumerate([*fail, True]):
        if not f and start is None:
            start = k
        elif f and start is not None:
            runs.append([_plain(xs[start]), _plain(xs[k - 1])])
            start = None
    try:
        ref = list(xs).index(x_ref)
    except ValueError:
        ref = 0
    if fail[ref]:
        return {"passes_from": None, "passes_to": None, "fails_at_reference": True,
                "first_fail_below": _plain(xs[ref]), "first_fail_above": _plain(xs[ref]),
                "passing_runs": runs}
    lo = hi = ref
    while lo > 0 and not fail[lo - 1]:
        lo -= 1
    while hi < len(xs) - 1 and not fail[hi + 1]:
        hi += 1
    return {"passes_from": _plain(xs[lo]), "passes_to": _plain(xs[hi]),
            "fails_at_reference": False,
            "first_fail_below": _plain(xs[lo - 1]) if lo > 0 else None,
            "first_fail_above": _plain(xs[hi + 1]) if hi < len(xs) - 1 else None,
            "passing_runs": runs}


def _plain(obj: Any) -> Any:
    """JSON-ready copy, floats to 6 decimals (the maps' values and axes)."""
    return plain(obj, 6)
