"""The pins (markers): how their tips follow the pad's deformation (:mod:`.kinematics`)
and an a-posteriori estimate of each tip's discretisation error (:mod:`.error`)."""
