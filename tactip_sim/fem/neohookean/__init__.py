"""The large-deformation reference: a compressible neo-Hookean pad with the same contact
(:mod:`.solver`: Newton iteration and load paths), its tangent's block pattern and factorisation
(:mod:`.blocks`), the penalty Coulomb law (:mod:`.friction`), the pins' ends against the window
(:mod:`.tips`, :mod:`.lowrank`) and stuck to it (:mod:`.stick`)."""
