"""``python -m tactip_sim.commands ...`` runs ``tactip ...`` (through the same entry point as
the console script, :func:`.launch.main`).

A Ctrl-C while the launcher itself loads (before :func:`.launch.main` takes over SIGINT; a
millisecond or two, longer on a loaded machine) ends the run like one after it: one line,
exit status 130 (docs/robustness.md)."""

import sys

try:
    from .launch import main
except KeyboardInterrupt:  # launch.py's own line and INTERRUPTED: it did not load
    print("\ntactip: interrupted", file=sys.stderr)
    sys.exit(130)

sys.exit(main())
