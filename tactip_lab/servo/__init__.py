"""Closed-loop grasp adjustment with the simulated fingertip in the loop (issue 20).

The reference paper's controller (Pestell et al. §III-D, §IV-B): fingers close until their
frames show contact, then base and distal joints are servoed by PID on the roll and pitch a
regressor predicts from each frame, with a time-out. Here every frame is pressed, rendered and
perceived by the shared chain (:mod:`tactip_lab.sampling.chain`); the controller sees only those
frames (through perception and the regressor) and its joint encoders.

Modules, in the order the data flows:

* :mod:`.params` - every physical and controller parameter, cited or marked assumed
* :mod:`.kinematics` - the finger model (joints orient the pad; rolling contact)
* :mod:`.objects` - the grasped objects (analytic shapes posed per finger)
* :mod:`.model` - the regressor, checked against the scene and tip
* :mod:`.plant` - one simulated finger: pose -> FEM -> frame -> observation (+ ground truth)
* :mod:`.pid`, :mod:`.controller` - the PID and the paper's phases and verdicts
* :mod:`.loop`, :mod:`.grasp` - the loop over fingers and frames; surface and object runs
* :mod:`.batch`, :mod:`.report` - random batches, summaries and charts
* :mod:`.cli` - ``tactip servo``
"""

from tactip_lab.servo.controller import OUTCOMES, FingerController
from tactip_lab.servo.grasp import RunResult, run_contacts, run_object, run_surface, servo_chain
from tactip_lab.servo.model import ServoModel, load_servo_model
from tactip_lab.servo.params import ServoParams
from tactip_lab.servo.pid import IncrementalPID, check_gains, closed_loop_poles

__all__ = ["OUTCOMES", "FingerController", "IncrementalPID", "RunResult", "ServoModel",
           "ServoParams", "check_gains", "closed_loop_poles", "load_servo_model",
           "run_contacts", "run_object", "run_surface", "servo_chain"]
