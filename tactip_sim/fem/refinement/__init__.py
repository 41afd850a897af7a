"""How well a mesh resolves a contact (:mod:`.resolution`) and the mesh refined
around a contact or the pins when it does not (:mod:`.refine`)."""
