"""Declarative field specifications for the scene schema.

Every scene key is a dataclass field whose ``metadata`` carries a :class:`Spec`: its
type, its allowed range or choices and a one-line description. The loader
(:mod:`tactip_sim.scene.load`) checks a TOML table against these specs generically, so a
new key needs one line here and nothing in the loader.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any


class SceneError(ValueError):
    """A scene file or scene value is malformed; the message names the key and the allowed range."""


@dataclass(frozen=True)
class Spec:
    """What one scene key may hold.

    kind : "float", "int", "bool", "str", "float_list", "int_list", "str_list"
    lo, hi : inclusive bounds unless ``lo_open``/``hi_open``; None = unbounded
    choices : allowed strings for kind "str"
    length : exact list length for list kinds (None = any, ``min_length`` applies)
    """

    kind: str
    doc: str
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False
    choices: tuple[str, ...] | None = None
    length: int | None = None
    min_length: int = 0

    def range_text(self) -> str:
        if self.choices is not None:
            return "one of " + ", ".join(repr(c) for c in self.choices)
        if self.lo is None and self.hi is None:
            return "any value"
        lo = "-inf" if self.lo is None else f"{self.lo:g}"
        hi = "inf" if self.hi is None else f"{self.hi:g}"
        left = "(" if (self.lo_open or self.lo is None) else "["
        right = ")" if (self.hi_open or self.hi is None) else "]"
        return f"{left}{lo}, {hi}{right}"

    def check_scalar(self, key: str, value: Any) -> Any:
        """Return ``value`` converted to this spec's Python type, or raise SceneError."""
        base = self.kind.removesuffix("_list")
        if base == "bool":
            if not isinstance(value, bool):
                raise SceneError(f"{key}={value!r} must be a boolean (true or false)")
            return value
        if base == "str":
            if not isinstance(value, str):
                raise SceneError(f"{key}={value!r} must be a string, {self.range_text()}")
            if self.choices is not None and value not in self.choices:
                raise SceneError(f"{key}={value!r} is not allowed: expected {self.range_text()}")
            return value
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise SceneError(f"{key}={value!r} must be a number in {self.range_text()}")
        if base == "int":
            if isinstance(value, float):
                if not value.is_integer():
                    raise SceneError(f"{key}={value!r} must be an integer in {self.range_text()}")
                value = int(value)
        else:
            value = float(value)
            if not math.isfinite(value):
                raise SceneError(f"{key}={value!r} must be finite, in {self.range_text()}")
        bad_lo = self.lo is not None and (value <= self.lo if self.lo_open else value < self.lo)
        bad_hi = self.hi is not None and (value >= self.hi if self.hi_open else value > self.hi)
        if bad_lo or bad_hi:
            raise SceneError(f"{key}={value!r} is out of range: allowed {self.range_text()}")
        return value

    def check(self, key: str, value: Any) -> Any:
        if not self.kind.endswith("_list"):
            return self.check_scalar(key, value)
        if not isinstance(value, list):
            raise SceneError(f"{key}={value!r} must be a list of {self.kind.removesuffix('_list')}")
        if self.length is not None and len(value) != self.length:
            raise SceneError(f"{key}={value!r} must have exactly {self.length} entries")
        if len(value) < self.min_length:
            raise SceneError(f"{key}={value!r} must have at least {self.min_length} entries")
        return tuple(self.check_scalar(f"{key}[{i}]", v) for i, v in enumerate(value))


def spec(default: Any, kind: str, doc: str, **kw: Any) -> Any:
    """A dataclass field carrying a :class:`Spec` (lists become tuples, so scenes stay frozen)."""
    if isinstance(default, list):
        default = tuple(default)
    return dataclasses.field(default=default, metadata={"spec": Spec(kind, doc, **kw)})


def positive(default: float, doc: str, hi: float | None = None) -> Any:
    return spec(default, "float", doc, lo=0.0, lo_open=True, hi=hi)


def nonneg(default: float, doc: str, hi: float | None = None) -> Any:
    return spec(default, "float", doc, lo=0.0, hi=hi)


def poisson(default: float) -> Any:
    return spec(
        default,
        "float",
        "Poisson's ratio (below 0.5: the solver is displacement-based)",
        lo=-1.0,
        lo_open=True,
        hi=0.5,
        hi_open=True,
    )
