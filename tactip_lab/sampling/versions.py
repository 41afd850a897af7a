"""What made a result: package versions and perception's results version, recorded in every
dataset's metadata and every study's summary."""

from __future__ import annotations

PACKAGES = ("tactip-sim", "numpy", "scipy", "mitsuba", "drjit", "scikit-fem", "pytetwild",
            "opencv-contrib-python-headless", "numba", "scikit-learn", "shapely", "dask")


def package_versions() -> dict[str, str]:
    """Installed version of each of :data:`PACKAGES` ("absent" when not installed)."""
    from importlib.metadata import PackageNotFoundError, version

    out = {}
    for pkg in PACKAGES:
        try:
            out[pkg] = version(pkg)
        except PackageNotFoundError:
            out[pkg] = "absent"
    return out


def physics_results_version() -> int:
    """``tactip_sim.fem.RESULTS_VERSION``: samples of another version must not be mixed in."""
    from tactip_sim.fem import RESULTS_VERSION

    return RESULTS_VERSION


def perception_results_version() -> int:
    """``perception.RESULTS_VERSION``: features of another version must not be mixed in."""
    import perception

    return perception.RESULTS_VERSION


__all__ = ["PACKAGES", "package_versions", "perception_results_version",
           "physics_results_version"]
