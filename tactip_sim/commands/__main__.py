"""``python -m tactip_sim.commands ...`` runs ``tactip ...`` (through the same entry point as
the console script, :func:`.launch.main`)."""

import sys

from .launch import main

sys.exit(main())
