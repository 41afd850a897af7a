"""The finite-element discretisation of the pad's mesh: P1/P2 Lagrange tetrahedra
(:mod:`.elements`) and the space built on a tet mesh (:mod:`.space`: nodes, the clamped window
face, the outer contact surface, point location and interpolation/gradient operators)."""
