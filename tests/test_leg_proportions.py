"""A leg whose calibrated thigh and shank are far apart in length is called implausible (report.leg_proportion_lines):
pyCGM2's ball-knee OpenSim models carried the knee centre down the shank on a real walk (docs/benchmarks.md)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pinocchio as pin

from calibrate.calibration.html import report_html
from calibrate.calibration.pipeline import calibrate
from calibrate.calibration.report import LEG_RATIO, calibration_report, summary_text
from calibrate.model.model import Parameters
from calibrate.model.urdf import urdf_text
from calibrate.problem.settings import Settings
from calibrate.simulation.simulate import simulate_gait


def _legs(text: str) -> dict[str, tuple[float, float]]:
    """Hip to knee and knee to ankle (m) per side, from the URDF's link origins at the neutral pose (Pinocchio)."""
    model = pin.buildModelFromXML(text)
    data = model.createData()
    pin.framesForwardKinematics(model, data, pin.neutral(model))

    def at(link: str) -> np.ndarray:
        return data.oMf[model.getFrameId(link)].translation

    return {s: (float(np.linalg.norm(at(f"tibia_{s}") - at(f"femur_{s}"))),
                float(np.linalg.norm(at(f"talus_{s}") - at(f"tibia_{s}")))) for s in "lr"}


def test_a_knee_carried_along_the_leg_is_implausible(human) -> None:  # noqa: ANN001
    """A simulated walk calibrates its legs within LEG_RATIO (no line); the same calibration with its right knee
    centre carried 60 % further down the femur is named, with the hip-to-knee and knee-to-ankle lengths the written
    URDF has (Pinocchio), in the summary, the report's flags and the HTML page."""
    cal = calibrate(human, simulate_gait(human, frames=40, noise_mm=1.0, seed=1).trial, Settings(max_iterations=20))
    legs = _legs(urdf_text(cal.model, cal.params))
    assert all(1 / LEG_RATIO < thigh / shank < LEG_RATIO for thigh, shank in legs.values())
    assert "hip to knee" not in summary_text(cal)
    p = cal.params
    centre = p.centre.copy()
    knee = cal.model.joint_index("knee_r")
    centre[knee] = 1.6 * centre[knee]
    carried = replace(cal, params=Parameters(p.scale, centre, p.axis, p.marker))
    thigh, shank = _legs(urdf_text(carried.model, carried.params))["r"]
    assert thigh / shank > LEG_RATIO
    lines = [line for line in summary_text(carried).splitlines() if "hip to knee" in line]
    assert lines == [f"  implausible  knee_r: hip to knee {1e3 * thigh:.0f} mm, knee to ankle {1e3 * shank:.0f} mm "
                     f"({thigh / shank:.2f} times), where adults' are about equal (Winter's proportions; real "
                     "calibrations 0.88-1.27): the knee centre was carried along the leg, which the trials' markers "
                     "do not hold (a ball knee's extra turns take up the skin's motion); the lab's knee centres as "
                     "markers (a marker map naming them) or a hinge knee hold it"]
    report = calibration_report(carried)
    flag = next(f for f in report["implausible_flags"] if "hip to knee" in f)
    assert f"implausible {flag.split(':')[0]}" in report_html(report)
