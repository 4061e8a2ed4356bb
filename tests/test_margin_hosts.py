"""New labels placed by their distances' margins (calibrate.seed.association.margin_hosts) where the trial's one
rigidity threshold, set by its most rigid markers, passes no segment whose markers ride on skin: a treadmill walk's
fifth-metatarsal markers beside a heel and toe that move 1-2 mm against each other (AddBiomechanics'
initial_off_treadmill: LMT5 and RMT5 left out, the feet posed by two markers each)."""

from __future__ import annotations

import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

from calibrate.calibration.pipeline import calibrate
from calibrate.model.model import load_model
from calibrate.problem.settings import Settings
from calibrate.seed.association import MARGIN_OWN, MARGIN_RATIO, associate_to_model, margin_hosts
from calibrate.simulation import simulate_squats

HUMAN = Path(__file__).resolve().parent.parent / "models" / "human.urdf"
MT5 = (0.12, 0.045, 0.01)  # on calcn_l, m: lateral to the heel-toe line
SKIN = 0.0015  # m per axis and frame: the heel, toe and MT5 markers' motion on the foot's skin
NOISE_MM = 0.3  # every other marker's


def _session():
    """Squats of a subject carrying LMT5 on the left foot, which the base model does not know; the foot's three
    markers moved by SKIN of independent skin motion, a label on the floor by as much.  Returns the trial and the
    subject's places of the foot's markers on calcn_l (m)."""
    extra = (f'  <link name="LMT5"><visual><geometry><sphere radius="0.007"/></geometry></visual></link>\n'
             f'  <joint name="LMT5_marker" type="fixed"><parent link="calcn_l"/><child link="LMT5"/>'
             f'<origin xyz="{MT5[0]} {MT5[1]} {MT5[2]}" rpy="0 0 0"/></joint>\n')
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "mt5.urdf"
        path.write_text(HUMAN.read_text().replace("</robot>", extra + "</robot>"))
        truth = load_model(path)
    sim = simulate_squats(truth, frames=200, noise_mm=NOISE_MM, seed=7)
    rng = np.random.default_rng(7)
    X = sim.trial.markers.copy()
    foot = [sim.trial.labels.index(n) for n in ("LHEE", "LTOE", "LMT5")]
    X[:, foot] += rng.normal(0.0, SKIN, (X.shape[0], len(foot), 3))
    floor = np.array([0.4, 0.6, 0.0]) + rng.normal(0.0, SKIN, (X.shape[0], 1, 3))
    trial = replace(sim.trial, labels=(*sim.trial.labels, "FLOOR"), markers=np.concatenate([X, floor], axis=1))
    s = sim.truth.scale[truth.segment_index("calcn_l")]
    return trial, {n: s * sim.truth.marker[truth.marker_index(n)] for n in ("LMT5", "LHEE", "LTOE")}


def _sd(trial, a: str, b: str) -> float:
    """SD over the frames of the distance between two labels (m), computed here from the positions."""
    i, j = trial.labels.index(a), trial.labels.index(b)
    return float(np.std(np.linalg.norm(trial.markers[:, i] - trial.markers[:, j], axis=1)))


def test_a_marker_beside_a_skin_moved_segment_is_placed_by_its_distances_margin():
    """The trial's threshold, set by its 0.3 mm markers, passes LMT5 on no segment (the heel and toe themselves
    fail it against each other); its distances to them vary as theirs do, several times less than to any other
    segment's, so it goes on calcn_l, with the figures as the distances give them.  The floor label varies alike
    against every segment and stays out."""
    base = load_model(HUMAN)
    trial, _ = _session()
    assoc = associate_to_model(base, trial)
    assert assoc["LMT5"].segment is None and assoc["FLOOR"].segment is None
    hosts = margin_hosts(base, trial, ["LMT5", "FLOOR"])
    h = hosts["LMT5"]
    assert h.segment == "calcn_l", h
    spread = max(_sd(trial, "LMT5", "LHEE"), _sd(trial, "LMT5", "LTOE"))
    own = _sd(trial, "LHEE", "LTOE")
    assert abs(h.spread - spread) < 0.02 * spread and abs(h.own - own) < 0.02 * own
    assert h.spread <= MARGIN_OWN * h.own and h.runner_up_spread >= MARGIN_RATIO * h.spread
    assert h.runner_up != "calcn_l" and h.reason().startswith(f"its distances to calcn_l's markers vary by "
                                                              f"{1e3 * h.spread:.1f} mm std")
    assert hosts["FLOOR"].segment is None


def test_the_calibration_fits_a_margin_placed_marker_where_it_rides():
    """calibrate places LMT5 on calcn_l by the margins (the poses, a two-marker foot's, leave it out) and fits it
    where the simulator put it on the subject's foot: its distances to the heel and toe within 3 mm of the
    subject's (distances, which no choice of the segment's frame changes)."""
    base = load_model(HUMAN)
    trial, places = _session()
    cal = calibrate(base, trial, Settings())
    placed = {m.label: m for m in cal.new_markers}
    assert placed["LMT5"].segment == "calcn_l", placed["LMT5"]
    assert placed["LMT5"].reason.startswith("its distances to calcn_l's markers"), placed["LMT5"].reason
    assert placed["FLOOR"].segment is None
    s = cal.params.scale[base.segment_index("calcn_l")]
    fitted = {n: s * cal.params.marker[cal.model.marker_index(n)] for n in places}
    for other in ("LHEE", "LTOE"):
        truth = np.linalg.norm(places["LMT5"] - places[other])
        assert abs(np.linalg.norm(fitted["LMT5"] - fitted[other]) - truth) < 0.003, (other, truth)
