"""The rig as it really collects data: the imperfections between a commanded pose and a frame
(:mod:`.sources`), and the elastomers' viscoelasticity they need (:mod:`.prony`). The
bottom of the lab's layers: it imports only ``tactip_sim``.
"""
