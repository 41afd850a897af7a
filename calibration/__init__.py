"""calibration: the reference paper's roll/pitch protocol run in simulation.

Sweeps (press -> render -> perceive) into resumable datasets on disk, regressors fitted on the
training sweep and scored on the test sets, the R² table beside the paper's, charts.
May import both ``tactip_sim`` and ``perception``.
"""

from .calibrate import CalibrationResult, calibrate
from .dataset import Dataset, DatasetError, SampleRecord
from .fit import PAPER_R2, features, fit_model, score
from .protocol import PoseSet, Tip, evaluation_sets, make_tip, training_set
from .sweep import SweepResult, SweepSpec, run_sweep

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
