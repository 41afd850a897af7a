"""A simulated TacTip against a real one: scene identification from a real rest frame
(``tactip identify``) and regressors fitted on simulated taps, scored on real ones
(``tactip sim2real``).
"""
