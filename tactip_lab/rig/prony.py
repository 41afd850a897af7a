"""Linear viscoelasticity of the pad's elastomers as a Prony series (a generalised Maxwell solid).

The normalised relaxation modulus is

    G(t) / G(0) = g_inf + sum_i g_i exp(-t / tau_i),   g_inf = 1 - sum_i g_i,

with ``g_i >= 0``, ``sum g_i < 1`` (a solid: some stiffness is left at long times) and
``tau_i > 0`` (s). Each term is a Maxwell branch (spring ``g_i`` in series with a dashpot of
relaxation time ``tau_i``) in parallel with the long-term spring ``g_inf``.

Two consequences for the rig (:mod:`tactip_lab.rig.sources`):

* **relaxation during the capture**: the fingertip is held at a pose while ~60 frames are
  taken over ~3 s; the modulus the frames see, averaged over the capture window, differs from
  the modulus the scene quotes (a durometer reading, taken at ``reference_s`` after the
  indenter lands). :meth:`Prony.capture_ratio` is that ratio;
* **hysteresis between poses**: after a pose is held and the plate lifted, the elastomer
  creeps back to rest; part of the previous pose's strain is still there when the next pose is
  captured. :meth:`Prony.residual_after_release` integrates the branches' internal variables
  exactly (a matrix exponential) for that fraction.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Prony:
    """A normalised Prony series.

    g : (k,) relative branch stiffnesses (each >= 0, sum < 1)
    tau_s : (k,) relaxation times (s, each > 0)
    name : the parameter's name in error messages (e.g. ``rig.skin_prony``)
    """

    g: tuple[float, ...] = ()
    tau_s: tuple[float, ...] = ()
    name: str = "prony"

    def __post_init__(self) -> None:
        g = _floats(self.g, f"{self.name}_g")
        tau = _floats(self.tau_s, f"{self.name}_tau_s")
        if len(g) != len(tau):
            raise ValueError(f"{self.name}_g has {len(g)} terms but {self.name}_tau_s has "
                             f"{len(tau)}: give one relaxation time per term")
        for i, v in enumerate(g):
            if v < 0:
                raise ValueError(f"{self.name}_g[{i}]={v:g} is negative: allowed [0, 1)")
        if sum(g) >= 1:
            raise ValueError(f"{self.name}_g sums to {sum(g):g}: allowed [0, 1) (a solid keeps "
                             "some stiffness at long times)")
        for i, v in enumerate(tau):
            if not v > 0:
                raise ValueError(f"{self.name}_tau_s[{i}]={v:g} must be > 0 (seconds)")
        object.__setattr__(self, "g", g)
        object.__setattr__(self, "tau_s", tau)

    @property
    def active(self) -> bool:
        return any(v > 0 for v in self.g)

    @property
    def g_inf(self) -> float:
        return 1.0 - float(sum(self.g))

    def relaxation(self, t_s: float | np.ndarray) -> np.ndarray:
        """G(t) / G(0) at times ``t_s`` (s, >= 0)."""
        t = np.asarray(t_s, dtype=float)
        out = np.full(t.shape, self.g_inf)
        for g, tau in zip(self.g, self.tau_s, strict=True):
            out = out + g * np.exp(-t / tau)
        return out

    def mean_relaxation(self, start_s: float, duration_s: float) -> float:
        """The mean of G(t) / G(0) over ``[start_s, start_s + duration_s]`` (closed form)."""
        if duration_s <= 0:
            return float(self.relaxation(start_s))
        total = self.g_inf * duration_s
        for g, tau in zip(self.g, self.tau_s, strict=True):
            total += g * tau * (np.exp(-start_s / tau) - np.exp(-(start_s + duration_s) / tau))
        return float(total / duration_s)

    def capture_ratio(self, *, delay_s: float, capture_s: float, reference_s: float) -> float:
        """The capture-averaged modulus over the modulus at ``reference_s`` (the time the
        scene's modulus was read): the factor the capture sees on the scene's modulus."""
        return self.mean_relaxation(delay_s, capture_s) / float(self.relaxation(reference_s))

    def residual_after_release(self, hold_s: float, after_s: float | np.ndarray) -> np.ndarray:
        """The strain left ``after_s`` seconds after a strain ``e0``, imposed at t = 0 and held
        for ``hold_s``, is released (stress-free recovery), as a fraction of ``e0``.

        The branches' viscous strains ``q_i`` relax towards the imposed strain while it is
        held (``q_i = e0 (1 - exp(-hold/tau_i))``); once free, the total strain is
        ``e = sum g_i q_i`` (zero stress, ``G(0) = 1``) and ``dq_i/dt = (e - q_i) / tau_i``,
        a linear system integrated exactly by its matrix exponential.
        """
        from scipy.linalg import expm

        s = np.atleast_1d(np.asarray(after_s, dtype=float))
        if not self.active:
            return np.zeros(s.shape) if np.ndim(after_s) else np.float64(0.0)
        g = np.asarray(self.g)
        rate = 1.0 / np.asarray(self.tau_s)
        q0 = 1.0 - np.exp(-hold_s * rate)
        a = rate[:, None] * (g[None, :] - np.eye(len(g)))
        out = np.array([g @ (expm(a * v) @ q0) for v in s.ravel()]).reshape(s.shape)
        return out if np.ndim(after_s) else np.float64(out[0])


def _floats(values: Sequence[float] | float, name: str) -> tuple[float, ...]:
    if isinstance(values, int | float) and not isinstance(values, bool):
        values = (values,)
    try:
        out = tuple(float(v) for v in values)
    except (TypeError, ValueError):
        raise ValueError(f"{name}={values!r} must be a list of numbers") from None
    for i, v in enumerate(out):
        if not np.isfinite(v):
            raise ValueError(f"{name}[{i}]={v!r} must be finite")
    return out


__all__ = ["Prony"]
