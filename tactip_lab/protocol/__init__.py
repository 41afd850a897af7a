"""The reference paper's roll/pitch protocol (``tactip calibrate``): sweeps per tip,
regressors of order 1-3, the R² table beside the paper's, charts, and the rig's error budget
(``tactip study rig``).
"""
