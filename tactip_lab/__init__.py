"""tactip_lab: what a lab does with the simulated fingertip, one folder a product.

Layers, bottom up: ``rig`` (the data collection's imperfections) -> ``sampling`` (pose sets,
the sample chain, sweeps, datasets) -> ``fitting`` (regressors on datasets) -> the products,
which never import each other: ``protocol`` (the paper's calibration), ``real`` (real sensors:
identification, sim-to-real), ``recognition`` (objects, marker selection), ``servo`` (the grasp
controller), ``studies`` (fidelity, stability) -> ``cli``. May import ``tactip_sim`` and
``perception``.
"""

from tactip_lab.fitting.fit import PAPER_R2, features, fit_model, score
from tactip_lab.protocol.calibrate import CalibrationResult, calibrate
from tactip_lab.sampling.dataset import Dataset, DatasetError, SampleRecord
from tactip_lab.sampling.poses import PoseSet, Tip, evaluation_sets, make_tip, training_set
from tactip_lab.sampling.sweep import SweepResult, SweepSpec, run_sweep

__all__ = [
    "PAPER_R2",
    "CalibrationResult",
    "Dataset",
    "DatasetError",
    "PoseSet",
    "SampleRecord",
    "SweepResult",
    "SweepSpec",
    "Tip",
    "calibrate",
    "evaluation_sets",
    "features",
    "fit_model",
    "make_tip",
    "run_sweep",
    "score",
    "training_set",
]
