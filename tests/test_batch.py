"""calibrate batch (issue 21 item 4): a manifest of generated subjects calibrated on a 2-worker Dask
LocalCluster; a broken trial reported without stopping the others; resume and --overwrite; bad manifests."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("distributed", reason="calibrate batch needs dask.distributed (the [batch] extra)")

from calibrate.calibration.batch import read_manifest, run_batch  # noqa: E402
from calibrate.errors import CalibrateError  # noqa: E402
from calibrate.io.read import read_trial  # noqa: E402
from calibrate.model.model import load_model  # noqa: E402
from calibrate.simulation.simulate import simulate_squats, write_simulation  # noqa: E402

HUMAN = Path(__file__).resolve().parent.parent / "models" / "human.urdf"


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    """Three generated subjects (80 squat frames each) and a manifest; S3's trial file is broken."""
    root = tmp_path_factory.mktemp("lab")
    model = load_model(HUMAN)
    for k, sid in enumerate(("S1", "S2", "S3")):
        write_simulation(simulate_squats(model, frames=80, noise_mm=1.0, seed=10 + k), root / sid)
    (root / "S3" / "trial.c3d").write_bytes(b"not a c3d file at all")
    lines = [f'[[subject]]\nid = "{sid}"\ntrials = ["{sid}/trial.c3d"]\nmodel = "{HUMAN}"\n'
             for sid in ("S1", "S2", "S3")]
    (root / "lab.toml").write_text("\n".join(lines) + 'mass = 70.0\n')
    return root


def test_batch_on_a_local_cluster_isolates_a_broken_subject_and_resumes(lab):
    out = lab / "out"
    seen = []
    rows = run_batch(read_manifest(lab / "lab.toml"), out, workers=2, progress=lambda r, k, n: seen.append((k, n)))
    status = {r["subject"]: r["status"] for r in rows}
    assert status["S1"] in ("ok", "not converged") and status["S2"] in ("ok", "not converged")
    assert status["S3"] == "failed" and "trial.c3d" in rows[2]["error"]
    assert sorted(seen) == [(1, 3), (2, 3), (3, 3)]
    for sid in ("S1", "S2"):
        folder = out / sid
        assert {p.name for p in folder.iterdir()} >= {"subject.urdf", "trial_motion.csv", "report.json", "report.html"}
        # The summary's RMS is the one in the subject's report, read back.
        rep = json.loads((folder / "report.json").read_text())
        row = next(r for r in rows if r["subject"] == sid)
        assert row["marker_rms_mm"] == pytest.approx(rep["markers"]["rms_mm"], abs=1e-5) and row["marker_rms_mm"] < 5
        assert read_trial(lab / sid / "trial.c3d").n_frames == 80
    with open(out / "summary.csv") as f:
        table = list(csv.DictReader(f))
    assert [r["subject"] for r in table] == ["S1", "S2", "S3"] and table[2]["status"] == "failed"
    index = (out / "index.html").read_text()
    assert 'href="S1/report.html"' in index and 'href="S2/report.json"' in index and "S3" in index
    # Resume: the done subjects are skipped (their outputs untouched), the failed one tried again.
    mtime = (out / "S1" / "report.json").stat().st_mtime_ns
    again = run_batch(read_manifest(lab / "lab.toml"), out, workers=2)
    assert [r["status"] for r in again] == ["skipped", "skipped", "failed"]
    assert (out / "S1" / "report.json").stat().st_mtime_ns == mtime
    # --overwrite (the command line): calibrated again.
    run = subprocess.run([sys.executable, "-m", "calibrate.cli", "batch", str(lab / "lab.toml"), "--out", str(out),
                          "--workers", "2", "--overwrite"], capture_output=True, text=True, timeout=600)
    assert run.returncode == 1, run.stderr  # S3 still fails
    assert (out / "S1" / "report.json").stat().st_mtime_ns != mtime
    assert "[3/3]" in run.stderr and "3 subjects: 2 ok, 1 failed" in run.stdout.replace("not converged", "ok")


def test_csv_manifest_and_bad_manifests(tmp_path):
    (tmp_path / "m.csv").write_text(f"subject,trials,model,markers,mass\nA,a.c3d;b.c3d,{HUMAN},,61.5\n")
    (s,) = read_manifest(tmp_path / "m.csv")
    assert s.id == "A" and [t.name for t in s.trials] == ["a.c3d", "b.c3d"] and s.mass == 61.5 and s.markers is None
    bad = {"x.toml": "[[subject]]\nid = \"A\"\nmodel = \"m.urdf\"\n",  # no trials
           "y.toml": "[[subject]]\nid = \"A\"\ntrials = [\"a.c3d\"]\nmodel = \"m.urdf\"\n[[subject]]\nid = \"A\"\n"
                     "trials = [\"b.c3d\"]\nmodel = \"m.urdf\"\n",  # the same id twice
           "z.csv": "name,trials\nA,a.c3d\n",  # no subject/model columns
           "w.txt": "anything"}
    for name, text in bad.items():
        (tmp_path / name).write_text(text)
        with pytest.raises(CalibrateError) as e:
            read_manifest(tmp_path / name)
        assert str(e.value).startswith(str(tmp_path / name)) and "\n" not in str(e.value)
    run = subprocess.run([sys.executable, "-m", "calibrate.cli", "batch", str(tmp_path / "x.toml"), "--out",
                          str(tmp_path / "o")], capture_output=True, text=True, timeout=120)
    assert run.returncode == 2 and "trials" in run.stderr and not (tmp_path / "o").exists()
    assert np.isfinite(s.mass)
