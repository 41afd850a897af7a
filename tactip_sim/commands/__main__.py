"""``python -m tactip_sim.commands ...`` runs ``tactip ...``."""

import sys

from .cli import main

sys.exit(main())
