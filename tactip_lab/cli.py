"""Every command of the lab's products, registered through the ``tactip.commands`` entry point
(so that ``tactip_sim`` never imports this package): each product adds its own."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    from tactip_lab.fitting.fitting_cli import register as register_fit
    from tactip_lab.protocol.protocol_cli import register as register_protocol
    from tactip_lab.protocol.protocol_cli import register_study as register_rig_study
    from tactip_lab.real.real_cli import register as register_real
    from tactip_lab.recognition.recognition_cli import register as register_recognition
    from tactip_lab.sampling.sampling_cli import register as register_sweep
    from tactip_lab.servo.servo_cli import register as register_servo
    from tactip_lab.studies.studies_cli import register as register_studies

    register_protocol(sub)
    register_sweep(sub)
    register_fit(sub)
    register_servo(sub)
    register_recognition(sub)
    p = sub.add_parser(
        "study", help="studies: fidelity, stability, rig (error budget)",
        description="Studies of the simulator itself: 'fidelity' charts time per frame against "
        "error for each fidelity level; 'stability' maps where each method fails; 'rig' "
        "budgets the real rig's sources of error.")
    studies = p.add_subparsers(dest="study", required=True, metavar="STUDY")
    register_studies(studies)
    register_rig_study(studies)
    register_real(sub)
