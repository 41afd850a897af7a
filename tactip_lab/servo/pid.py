"""A discrete PID in velocity (incremental) form and the stability of the servo loop.

The controller of the paper servoes a joint in position mode on a predicted angle: each frame
it moves the joint by

    du_k = kp (e_k - e_{k-1}) + ki dt e_k + (kd / dt) (e_k - 2 e_{k-1} + e_{k-2})

from where the joint's encoder says it is. Summed, this is the textbook positional PID
``u = kp e + ki sum(e) dt + kd de/dt``; taking the increment from the measured joint angle
means a joint held back by its speed or range limit does not wind the integral up.

The nominal loop: the joint reaches its command within a frame and the next frame shows it
(one frame of delay), and the regressor reads the relative angle with slope ``g`` (1 for a
perfect one): ``e_{k+1} = s - g u_k``. Its characteristic polynomial (:func:`closed_loop_poles`)

    z^3 + (g (kp + ki dt + kd/dt) - 1) z^2 - g (kp + 2 kd/dt) z + g kd/dt = 0

is stable when every root lies inside the unit circle. With kp = kd = 0 this is
``z = 1 - g ki dt``: stable for 0 < g ki dt < 2, fastest at g ki dt = 1.
"""

from __future__ import annotations

import numpy as np


class IncrementalPID:
    """PID in velocity form on a scalar or vector error.

    Parameters
    ----------
    kp : proportional gain (output units per error unit)
    ki : integral gain (1/s)
    kd : derivative gain (s)
    dt : seconds per step (> 0)

    Examples
    --------
    Integral-only control of a static unit plant with one step of delay, ``ki dt = 0.5``: the
    error halves each step.

    >>> pid = IncrementalPID(0.0, 10.0, 0.0, 0.05)
    >>> u, errors = 0.0, []
    >>> for _ in range(4):
    ...     e = 1.0 - u
    ...     errors.append(e)
    ...     u += float(pid.step(e))
    >>> errors
    [1.0, 0.5, 0.25, 0.125]
    """

    def __init__(self, kp: float, ki: float, kd: float, dt: float) -> None:
        if not (np.isfinite(dt) and dt > 0):
            raise ValueError(f"dt={dt!r} is out of range: allowed (0, inf) s")
        for name, v in (("kp", kp), ("ki", ki), ("kd", kd)):
            if not np.isfinite(v):
                raise ValueError(f"{name}={v!r} must be finite")
        self.kp, self.ki, self.kd, self.dt = float(kp), float(ki), float(kd), float(dt)
        self.reset()

    def reset(self, previous_error: np.ndarray | float | None = None) -> None:
        """Forget the error history. ``None`` (bumpless): the next step's P and D increments
        start from its own error, so switching the loop on does not kick the output; a
        value: the error before the next step (0 makes the summed output the positional
        PID's from rest)."""
        e = None if previous_error is None else np.asarray(previous_error, dtype=float)
        self._e1: np.ndarray | None = e
        self._e2: np.ndarray | None = e

    def step(self, error: np.ndarray | float) -> np.ndarray:
        """The output increment for this step's ``error`` (same shape)."""
        e = np.asarray(error, dtype=float)
        e1 = e if self._e1 is None else self._e1
        e2 = e1 if self._e2 is None else self._e2
        du = (self.kp * (e - e1) + self.ki * self.dt * e
              + self.kd / self.dt * (e - 2.0 * e1 + e2))
        self._e2, self._e1 = e1, e
        return du


def closed_loop_poles(kp: float, ki: float, kd: float, dt: float, *, plant_gain: float = 1.0
                      ) -> np.ndarray:
    """Poles (complex, up to 3) of the nominal servo loop (module docstring)."""
    g, kdd = float(plant_gain), float(kd) / float(dt)
    coeffs = [1.0, g * (kp + ki * dt + kdd) - 1.0, -g * (kp + 2.0 * kdd), g * kdd]
    while len(coeffs) > 1 and coeffs[-1] == 0.0:
        coeffs = coeffs[:-1]  # z = 0 roots carry no dynamics
    return np.roots(coeffs)


def spectral_radius(kp: float, ki: float, kd: float, dt: float, *, plant_gain: float = 1.0
                    ) -> float:
    """Largest pole magnitude: < 1 stable, and the error shrinks by about this per step."""
    poles = closed_loop_poles(kp, ki, kd, dt, plant_gain=plant_gain)
    return float(np.max(np.abs(poles))) if len(poles) else 0.0


def stable_ki_range(kp: float, kd: float, dt: float, *, plant_gain: float = 1.0,
                    n: int = 4001) -> tuple[float, float] | None:
    """The interval of ``ki`` (1/s) that makes the nominal loop stable with these ``kp`` and
    ``kd`` (scanned over ki dt in (-1, 3) and refined by bisection), or None when there is
    none."""
    grid = np.linspace(-1.0, 3.0, n) / dt
    ok = np.array([spectral_radius(kp, k, kd, dt, plant_gain=plant_gain) < 1.0 for k in grid])
    if not ok.any():
        return None
    idx = np.flatnonzero(ok)
    lo_i, hi_i = idx[0], idx[-1]

    def edge(a: float, b: float) -> float:  # a stable, b not
        for _ in range(60):
            m = 0.5 * (a + b)
            if spectral_radius(kp, m, kd, dt, plant_gain=plant_gain) < 1.0:
                a = m
            else:
                b = m
        return 0.5 * (a + b)

    lo = edge(grid[lo_i], grid[lo_i - 1]) if lo_i > 0 else grid[0]
    hi = edge(grid[hi_i], grid[hi_i + 1]) if hi_i < n - 1 else grid[-1]
    return float(lo), float(hi)


def gain_margin(kp: float, ki: float, kd: float, dt: float, *, g_max: float = 20.0) -> float:
    """The largest regressor slope ``g`` (see the module docstring) up to ``g_max`` for which
    the loop stays stable: a regressor over-reading the angle by this factor makes it ring
    out of control."""
    lo, hi = 1e-6, g_max
    if spectral_radius(kp, ki, kd, dt, plant_gain=hi) < 1.0:
        return hi
    if spectral_radius(kp, ki, kd, dt, plant_gain=lo) >= 1.0:
        return 0.0
    for _ in range(60):
        m = 0.5 * (lo + hi)
        if spectral_radius(kp, ki, kd, dt, plant_gain=m) < 1.0:
            lo = m
        else:
            hi = m
    return lo


def check_gains(kp: float, ki: float, kd: float, dt: float) -> None:
    """Raise ValueError when the gains make the nominal loop unstable, naming them and the
    stable range of ``ki`` for the given ``kp`` and ``kd``."""
    rho = spectral_radius(kp, ki, kd, dt)
    if rho < 1.0:
        return
    rng = stable_ki_range(kp, kd, dt)
    hint = ("no ki makes it stable with these kp and kd" if rng is None else
            f"with kp={kp:g} and kd={kd:g}, ki must lie in ({rng[0]:.3g}, {rng[1]:.3g}) 1/s")
    raise ValueError(f"the gains kp={kp:g}, ki={ki:g}, kd={kd:g} make the servo loop unstable "
                     f"at {1 / dt:g} Hz (closed-loop pole of magnitude {rho:.3g} >= 1 with a "
                     f"perfect regressor and one frame of delay): {hint}")


__all__ = ["IncrementalPID", "check_gains", "closed_loop_poles", "gain_margin",
           "spectral_radius", "stable_ki_range"]
