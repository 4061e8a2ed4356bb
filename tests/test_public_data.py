"""scripts/public_data.py: a repository's trial files written flat under the sweeps' names, read back byte for byte."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))
import public_data  # noqa: E402


def _git(cwd: Path, *args: str) -> None:
    subprocess.run(["git", "-c", "user.name=t", "-c", "user.email=t@t", *args], cwd=cwd, check=True,
                   capture_output=True)


def test_trial_files_come_out_flat_under_their_paths(tmp_path, capsys):
    """Two trial files below a folder (one with an upper-case suffix) and one outside it, a text file beside: the
    two below it come out as PREFIX__sub__name with their bytes; a file already there is kept unless --overwrite; a
    bad source or a folder that is no git directory: one line, exit 2."""
    repo = tmp_path / "repo"
    (repo / "Input" / "Samples" / "PiG").mkdir(parents=True)
    (repo / "Input" / "Samples" / "PiG" / "walk.C3D").write_bytes(b"\x02\x50 c3d bytes")
    (repo / "Input" / "Samples" / "static.trc").write_text("PathFileType\t4\n")
    (repo / "Input" / "Samples" / "notes.txt").write_text("not a trial")
    (repo / "elsewhere.c3d").write_bytes(b"outside")
    _git(repo, "init", "-q")
    _git(repo, "add", ".")
    _git(repo, "commit", "-q", "-m", "data")
    out = tmp_path / "flat"
    assert public_data.main([f"{repo / '.git'}:btk:Input/Samples", "--into", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["btk__PiG__walk.C3D", "btk__static.trc"]
    assert (out / "btk__PiG__walk.C3D").read_bytes() == b"\x02\x50 c3d bytes"
    assert "2 files written" in capsys.readouterr().out
    (out / "btk__static.trc").write_text("edited")
    assert public_data.main([f"{repo / '.git'}:btk:Input/Samples", "--into", str(out)]) == 0
    assert (out / "btk__static.trc").read_text() == "edited"
    assert public_data.main([f"{repo / '.git'}:btk:Input/Samples", "--into", str(out), "--overwrite"]) == 0
    assert (out / "btk__static.trc").read_text() == "PathFileType\t4\n"
    assert public_data.main([f"{repo / '.git'}:all", "--into", str(tmp_path / "all")]) == 0  # the whole tree
    assert "all__elsewhere.c3d" in [p.name for p in (tmp_path / "all").iterdir()]
    capsys.readouterr()
    assert public_data.main([str(repo), "--into", str(out)]) == 2
    assert "give GITDIR:PREFIX" in capsys.readouterr().err
    assert public_data.main([f"{tmp_path}:x", "--into", str(out)]) == 2
    assert "not a git directory" in capsys.readouterr().err
