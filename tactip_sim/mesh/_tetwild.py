"""The child process that runs pytetwild (``python -m tactip_sim.mesh._tetwild IN OUT``).

pytetwild writes ``__tracked_surface.stl`` into the current directory, and has no option to
put it elsewhere. :func:`tactip_sim.mesh.tetra.tetrahedralise` therefore runs it here, in a
child process started in a temporary directory, so the calling process never changes its own
working directory. IN is an ``.npz`` of pytetwild's keyword arguments (arrays and 0-d
scalars); OUT receives ``nodes`` and ``tets``. Nothing else imports this module.
"""

from __future__ import annotations

import sys

import numpy as np


def main(argv: list[str]) -> int:
    import signal

    import pytetwild

    # the parent holds SIGINT and SIGTERM while it starts this process, which inherits the
    # mask: take them again, so that an interrupt reaches the mesher as it would any command
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})

    src, dst = argv
    with np.load(src) as data:
        kw = {k: (data[k].item() if data[k].ndim == 0 else data[k]) for k in data.files}
    nodes, tets = pytetwild.tetrahedralize(kw.pop("vertices"), kw.pop("faces"), **kw)
    np.savez(dst, nodes=np.asarray(nodes, dtype=np.float64), tets=np.asarray(tets))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
