"""The linear-elastic pad and its solves: stiffness and factorisation
(:mod:`.elasticity`), the discretised body and its cache key (:mod:`.model`), the full and
reduced (precomputed compliance) operators (:mod:`.full`, :mod:`.reduced`), Coulomb friction
(:mod:`.friction`), pins stopping at the window (:mod:`.window`) and load paths
(:mod:`.loadpath`)."""
