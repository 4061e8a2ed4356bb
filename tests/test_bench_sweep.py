"""scripts/bench_sweep.py: every trial file under a folder calibrated by the command line, a row per file, and what
changed against an earlier run."""

import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))
import bench_sweep  # noqa: E402

from calibrate.io.c3d import write_c3d  # noqa: E402
from calibrate.simulation import simulate_squats  # noqa: E402


def test_a_sweep_records_each_calibration_and_refusal_and_what_changed(human, tmp_path, capsys):
    """A simulated squat and an empty file: the squat's row carries the report's marker RMS and the URDF's md5, the
    empty file's its one-line refusal; compared with an earlier run whose squat wrote other bits and whose empty file
    calibrated, the two changes are named and nothing else."""
    data = tmp_path / "data"
    (data / "sub").mkdir(parents=True)
    sim = simulate_squats(human, frames=80, noise_mm=1.0, seed=5)
    write_c3d(data / "sub" / "squat.C3D", sim.trial)
    (data / "empty.c3d").write_bytes(b"")
    (data / "notes.txt").write_text("not a trial")
    assert [p.name for p in bench_sweep.trial_files([data])] == ["empty.c3d", "squat.C3D"]
    out = tmp_path / "now.json"
    assert bench_sweep.main([str(data), "--model", str(ROOT / "models" / "human.urdf"), "--json", str(out)]) == 0
    rows = {Path(r["file"]).name: r for r in json.loads(out.read_text())["files"]}
    squat, empty = rows["squat.C3D"], rows["empty.c3d"]
    assert squat["rc"] == 0 and squat["converged"] and len(squat["urdf_md5"]) == 32
    assert 0.5 < squat["rms_mm"] < 3.0  # 1 mm of simulated noise per axis: ~1.7 mm in 3-D
    assert squat["implausible"] == [] and squat["root_unplaced"] == 0.0  # every marker in every frame
    assert empty["rc"] == 2 and "empty.c3d: file is empty" in empty["error"] and "<scratch>" not in empty["error"]
    before = json.loads(out.read_text())
    for r in before["files"]:
        if r["file"].endswith("squat.C3D"):
            r["urdf_md5"], r["rms_mm"] = "0" * 32, 9.0
        else:
            r.update(rc=0, urdf_md5="1" * 32, rms_mm=1.0, implausible=[])
    changes = bench_sweep.compare(before, json.loads(out.read_text()))
    assert changes == ["empty.c3d: rc 0 -> 2 (" + empty["error"] + ")",
                       f"squat.C3D: URDF changed, marker RMS 9.000 -> {squat['rms_mm']:.3f} mm"]
    assert bench_sweep.compare(json.loads(out.read_text()), json.loads(out.read_text())) == []
    capsys.readouterr()
    assert bench_sweep.main([str(tmp_path / "nowhere")]) == 2
    assert "nowhere: not a folder" in capsys.readouterr().err
