"""Rigid indenters against the pad, independent of how the pad is modelled: poses
(:mod:`.pose`), the indenters and their placement (:mod:`.indenters`, :mod:`.meshgeom`), the
frictionless complementarity problem and its solvers (:mod:`.lcp`), the result of a press
(:mod:`.state`) and the closed-form answers the solvers are checked against (:mod:`.analytic`)."""
