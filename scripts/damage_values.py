"""Damaged values, not bytes: a real trial's marker values damaged as labs' recordings are, each copy calibrated and
compared with the undamaged trial's calibration (scripts/fuzz_inputs.py damages the files' bytes).

Kinds of damage (`--kinds`; each copy one kind, its sizes and places drawn from `--seed`):

- ghost: 1-6 runs of 1-3 frames of a marker 0.3-3 m off (a wrong ray match);
- ghost-gap: one such frame just before a gap of 5-20 frames (no jump back bounds it);
- fallen: a marker on the floor (7 mm up) from a frame in the trial's middle half to its end;
- latefall: the same for the trial's last 5-60 frames only (under one 0.5 s window at 100-120 Hz; not in the default
  cycle, so that the default's copies stay those documented: `--kinds latefall`);
- frozen: a marker at its first frame's place for the whole trial (stuck to something);
- gaps: 1-4 stretches of 5-60 frames of a marker unseen;
- swap: two markers' labels exchanged for 5-30 frames;
- longswap: two markers' labels exchanged for 0.5 s to half the trial (no jump back within a second);
- endswap: two markers' labels exchanged from a frame in the trial's middle half to its end, or from its start to
  such a frame (one exchange, no jump back);
- noisy: a marker given white noise of 3 mm to 1 m SD (log-uniform), throughout or in a stretch of 60-200 frames.

What must hold for each copy: `calibrate` returns (no exception, no refusal: the damage leaves a trial worth
calibrating); it names no label on a `check label` line that the undamaged trial's calibration does not; it says
`still only` exactly where that one does; and every joint centre stays within `--tol-mm` or 3 of its posterior SDs
(the larger) of that one's, or of the centre the same copy gives with its damaged positions unseen instead (what a
perfect check would leave: a marker lost for the whole trial moves a centre by the information it took, not by the
check's doing; pig_walk's walk without RFHD moves its lumbar centre 27 mm, 3 posterior SDs being 25).

`--ik`: the damage goes to `calibrate ik` instead (a subject calibrated once, on pig_walk's static and the undamaged
walk, by the command line; each damaged copy of the walk written as a C3D and fitted by `calibrate ik` with the
calibration's report, as a lab fits its subject's other trials).  What must hold: `calibrate ik` returns, and every
joint coordinate of every frame stays within `--tol-deg` of its angle in the undamaged walk's fit or in the fit of the
same copy with the damaged positions unseen instead, which a perfect check would leave (a marker fewer moves a pose,
and not by the check's doing: pig_walk's left ankle turns 50 deg on its toe marker alone).

    python scripts/damage_values.py [--case pig_walk|gait2392|rajagopal] [--trial walk|static] [--frames 300]
        [--n 30] [--seed 0] [--kinds ...] [--ik [--tol-deg 10]] [--json F]

Data: ../shared/data/real/pig_walk (Plug-in Gait, 120 Hz) on models/human.urdf, in process; `--case gait2392` or
`--case rajagopal`: OpenSim's example trials (TRC, y up) on their own .osim and marker set (the floor for `fallen` is
the lab's: its up axis read as the one along which a frame's markers spread most).  No timings: a check, not a
benchmark."""

from __future__ import annotations

import argparse
import json
import sys
import traceback
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PIG = ROOT.parent / "shared" / "data" / "real" / "pig_walk"
REAL = ROOT.parent / "shared" / "data" / "real"
KINDS = ("ghost", "ghost-gap", "fallen", "frozen", "gaps", "swap", "noisy", "longswap", "endswap")
EXTRA_KINDS = ("latefall",)  # asked for by name only
# Each case: its base model (and OpenSim marker set), its walk and its static.
CASES = {"pig_walk": (ROOT / "models" / "human.urdf", None, PIG / "walk.c3d", PIG / "static.c3d"),
         "gait2392": (REAL / "gait2392" / "gait2392.osim", REAL / "gait2392" / "gait2392_Scale_MarkerSet.xml",
                      REAL / "gait2392" / "subject01_walk1.trc", REAL / "gait2392" / "subject01_static.trc"),
         "rajagopal": (REAL / "rajagopal_walk" / "Rajagopal2016.osim",
                       REAL / "rajagopal_walk" / "markerset_walk_preScale.xml",
                       REAL / "rajagopal_walk" / "motion_capture_walk.trc",
                       REAL / "rajagopal_walk" / "static_walk_1.trc")}


def damage(X: np.ndarray, kind: str, rng: np.random.Generator) -> tuple[np.ndarray, str]:
    """A damaged copy of the markers X (frames, markers, 3; m) and what was done, in words (marker indices)."""
    X = X.copy()
    F, M, _ = X.shape

    def direction() -> np.ndarray:
        v = rng.normal(size=3)
        return v / np.linalg.norm(v)

    if kind == "ghost":
        done = []
        for _ in range(int(rng.integers(1, 7))):
            k, f, n, size = int(rng.integers(M)), int(rng.integers(F - 3)), int(rng.integers(1, 4)), rng.uniform(0.3, 3)
            X[f:f + n, k] += size * direction()
            done.append(f"marker {k} frames {f}-{f + n - 1} {size:.2f} m")
        return X, "; ".join(done)
    if kind == "ghost-gap":
        k, f, n = int(rng.integers(M)), int(rng.integers(1, F - 25)), int(rng.integers(5, 21))
        size = rng.uniform(0.3, 3)
        X[f, k] += size * direction()
        X[f + 1:f + 1 + n, k] = np.nan
        return X, f"marker {k} frame {f} {size:.2f} m, then {n} frames unseen"
    if kind in ("fallen", "latefall"):
        k = int(rng.integers(M))
        f = int(rng.integers(F // 4, 3 * F // 4)) if kind == "fallen" else F - int(rng.integers(5, 61))
        at = X[f, k].copy()
        if not np.all(np.isfinite(at)):
            return X, "none (unseen where it would fall)"
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            up = int(np.argmax(np.nanmedian(np.nanmax(X, axis=1) - np.nanmin(X, axis=1), axis=0)))  # a body's height
        at[up] = 0.007
        X[f:, k] = at
        return X, f"marker {k} on the floor from frame {f}"
    if kind == "frozen":
        k = int(rng.integers(M))
        first = np.flatnonzero(np.all(np.isfinite(X[:, k]), axis=1))
        if first.size == 0:
            return X, "none (never seen)"
        X[:, k] = X[first[0], k]
        return X, f"marker {k} at frame {first[0]}'s place throughout"
    if kind == "gaps":
        done = []
        for _ in range(int(rng.integers(1, 5))):
            k, n = int(rng.integers(M)), int(rng.integers(5, 61))
            f = int(rng.integers(F - n))
            X[f:f + n, k] = np.nan
            done.append(f"marker {k} frames {f}-{f + n - 1}")
        return X, "; ".join(done)
    if kind == "swap":
        a, b = (int(v) for v in rng.choice(M, size=2, replace=False))
        n = int(rng.integers(5, 31))
        f = int(rng.integers(F - n))
        X[f:f + n, [a, b]] = X[f:f + n, [b, a]]
        return X, f"markers {a} and {b} exchanged in frames {f}-{f + n - 1}"
    if kind == "longswap":
        a, b = (int(v) for v in rng.choice(M, size=2, replace=False))
        n = int(rng.integers(60, F // 2 + 1))
        f = int(rng.integers(F - n + 1))
        X[f:f + n, [a, b]] = X[f:f + n, [b, a]]
        return X, f"markers {a} and {b} exchanged in frames {f}-{f + n - 1}"
    if kind == "endswap":
        a, b = (int(v) for v in rng.choice(M, size=2, replace=False))
        f = int(rng.integers(F // 4, 3 * F // 4))
        f0, f1 = (f, F) if rng.random() < 0.5 else (0, f)
        X[f0:f1, [a, b]] = X[f0:f1, [b, a]]
        return X, f"markers {a} and {b} exchanged in frames {f0}-{f1 - 1}"
    if kind == "noisy":
        k, sd = int(rng.integers(M)), float(np.exp(rng.uniform(np.log(0.003), np.log(1.0))))
        f, n = (0, F) if rng.random() < 0.5 else (int(rng.integers(F - 60)), int(rng.integers(60, 201)))
        n = min(n, F - f)
        X[f:f + n, k] += rng.normal(scale=sd, size=(n, 3))
        return X, f"marker {k} noise {1e3 * sd:.0f} mm SD in frames {f}-{f + n - 1}"
    raise ValueError(f"unknown kind {kind}")


def unseen_instead(markers: np.ndarray, damaged: np.ndarray, kind: str) -> np.ndarray:
    """`markers` (frames, markers, 3) with every position the damage changed unseen (NaN): what a perfect check
    of the copy `damaged` would leave.  A frozen marker's first frame too: nothing tells when a marker stuck at its
    first place got stuck."""
    touched = ~((damaged == markers) | (np.isnan(damaged) & np.isnan(markers))).all(axis=2)
    if kind == "frozen":
        touched[:, touched.any(axis=0)] = True
    return np.where(touched[..., None], np.nan, markers)


def run(trial_name: str, frames: int, n: int, seed: int, kinds: list[str], tol_mm: float,
        case: str = "pig_walk") -> dict:
    from calibrate import calibrate, load_model, read_trial
    from calibrate.errors import CalibrateError
    from calibrate.io.trial import Trial

    model_path, marker_set, walk, static = CASES[case]
    model = load_model(model_path, marker_set)
    path = walk if trial_name == "walk" else static
    raw = read_trial(path)
    trial = raw.select([lab for lab in raw.labels if lab in set(model.marker_names)])
    trial = Trial(trial.labels, np.array(trial.markers[:frames]), trial.rate, 0, path.name)

    def summary(cal) -> dict:
        sd = {c.item: float(np.linalg.norm(c.std)) for c in cal.changes if c.group == "centre"}  # mm
        return {"centres": np.array(cal.params.centre), "labels": sorted({m.label for _, m in cal.misplaced}),
                "still": cal.still_only is not None, "rms_mm": 1e3 * cal.marker_rms,
                "sd_mm": np.array([sd.get(j.name, np.nan) for j in model.joints])}

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = summary(calibrate(model, trial))
    print(f"{case} {trial_name}: {trial.n_frames} frames, {len(trial.labels)} markers; undamaged: marker RMS "
          f"{ref['rms_mm']:.2f} mm, labels to check {ref['labels'] or 'none'}, still only {ref['still']}", flush=True)
    names = [j.name for j in model.joints]
    rng = np.random.default_rng(seed)
    rows, findings = [], []
    for i in range(n):
        kind = kinds[i % len(kinds)]
        X, what = damage(np.array(trial.markers), kind, rng)
        what = " ".join(w if not w.isdigit() else w for w in what.split())
        for k in sorted(range(len(trial.labels)), key=lambda k: -k):  # marker indices as labels, in words
            what = what.replace(f"marker {k} ", f"{trial.labels[k]} ").replace(f"markers {k} ", f"{trial.labels[k]} ")
            what = what.replace(f"and {k} ", f"and {trial.labels[k]} ")
        row = {"kind": kind, "damage": what}
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                got = summary(calibrate(model, Trial(trial.labels, X, trial.rate, 0, trial.source)))
        except CalibrateError as e:
            row["outcome"] = f"refused: {e}"
        except Exception as e:  # noqa: BLE001 - any other exception is the finding
            row["outcome"] = f"{type(e).__name__}: {e}"
            row["traceback"] = traceback.format_exc(limit=4)
        else:
            # a centre's shift against the larger of the tolerance and 3 posterior SDs of the undamaged calibration:
            # a centre its trial leaves to the priors (a forearm's) moves 20 mm with a few frames' gaps
            allowed = np.fmax(tol_mm, 3.0 * ref["sd_mm"]) / 1e3
            shift = np.linalg.norm(got["centres"] - ref["centres"], axis=1)
            if np.any(shift > allowed):
                # Against the same copy with its damaged positions unseen too (calibrated only where needed): the
                # nearer of the two references counts.
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    unseen = summary(calibrate(model, Trial(trial.labels, unseen_instead(trial.markers, X, kind),
                                                            trial.rate, 0, trial.source)))
                shift = np.fmin(shift, np.linalg.norm(got["centres"] - unseen["centres"], axis=1))
            worst = int(np.argmax(shift / allowed))
            row.update(rms_mm=round(got["rms_mm"], 2), centre_shift_mm=round(1e3 * float(shift[worst]), 1),
                       worst_joint=names[worst], labels=got["labels"], still=got["still"])
            bad = []
            if shift[worst] > allowed[worst]:
                bad.append(f"{names[worst]} moved {1e3 * shift[worst]:.1f} mm (3 SDs: {3 * ref['sd_mm'][worst]:.1f}) "
                           "from the undamaged trial's and from its own with the damage unseen")
            if set(got["labels"]) - set(ref["labels"]):
                bad.append(f"labels to check {sorted(set(got['labels']) - set(ref['labels']))}")
            if got["still"] != ref["still"]:
                bad.append(f"still only {got['still']}, undamaged {ref['still']}")
            row["outcome"] = "; ".join(bad) if bad else "ok"
        rows.append(row)
        if row["outcome"] != "ok":
            findings.append(row)
        print(f"  {i:3d} {kind:9s} {row['outcome'][:90]:90s} | {what[:80]}", flush=True)
    counts: dict[str, int] = {}
    for r in rows:
        key = f"{r['kind']}: {'ok' if r['outcome'] == 'ok' else 'finding'}"
        counts[key] = counts.get(key, 0) + 1
    return {"case": case, "trial": trial_name, "frames": trial.n_frames, "seed": seed, "tol_mm": tol_mm,
            "undamaged_rms_mm":
            round(ref["rms_mm"], 3), "counts": counts, "findings": findings, "copies": rows}


def run_ik(frames: int, n: int, seed: int, kinds: list[str], tol_deg: float) -> dict:
    """Each damaged copy of pig_walk's walk fitted by `calibrate ik` to the subject calibrated on the static and the
    undamaged walk; its angles against the undamaged walk's fit, away from the damaged frames."""
    import contextlib
    import io
    import tempfile

    from calibrate import load_model, read_trial
    from calibrate.cli.main import main as cli
    from calibrate.io.c3d import write_c3d
    from calibrate.io.motion import read_motion_csv
    from calibrate.io.trial import Trial

    tmp = Path(tempfile.mkdtemp(prefix="damage_ik_"))
    raw = read_trial(PIG / "walk.c3d")
    raw = raw.select([lab for lab in raw.labels if lab in set(load_model(ROOT / "models" / "human.urdf").marker_names)])
    trial = Trial(raw.labels, np.array(raw.markers[:frames]), raw.rate, 0, "walk.c3d")
    write_c3d(tmp / "walk.c3d", trial)
    with contextlib.redirect_stderr(io.StringIO()), contextlib.redirect_stdout(io.StringIO()), \
            warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if cli([str(PIG / "static.c3d"), str(tmp / "walk.c3d"), str(ROOT / "models" / "human.urdf"),
                "-o", str(tmp / "subject"), "-q"]) not in (0, 1):
            raise RuntimeError("the undamaged calibration failed")
    subject, report = tmp / "subject.urdf", tmp / "static_report.json"  # (named after the first trial)
    (tmp / "fits").mkdir()

    def ik(path: Path) -> np.ndarray:
        with contextlib.redirect_stderr(io.StringIO()), contextlib.redirect_stdout(io.StringIO()):
            code = cli(["ik", str(path), str(subject), "--report", str(report), "-o", str(tmp / "fits"),
                        "--overwrite", "-q"])
        if code != 0:
            raise RuntimeError(f"calibrate ik exit {code}")
        return read_motion_csv(tmp / "fits" / f"{path.stem}_motion.csv").angles

    undamaged = ik(tmp / "walk.c3d")
    names = list(read_motion_csv(tmp / "fits" / "walk_motion.csv").dof_names)
    print(f"walk: {trial.n_frames} frames, {len(trial.labels)} labels; subject calibrated on static + walk", flush=True)
    rng = np.random.default_rng(seed)
    rows, findings = [], []
    for i in range(n):
        kind = kinds[i % len(kinds)]
        X, what = damage(np.array(trial.markers), kind, rng)
        for k in sorted(range(len(trial.labels)), key=lambda k: -k):
            what = what.replace(f"marker {k} ", f"{trial.labels[k]} ").replace(f"markers {k} ", f"{trial.labels[k]} ")
            what = what.replace(f"and {k} ", f"and {trial.labels[k]} ")
        row = {"kind": kind, "damage": what}
        path = tmp / f"copy{i}.c3d"
        write_c3d(path, Trial(trial.labels, X, trial.rate, 0, path.name))
        # The same copy with the damaged positions unseen instead (what a perfect check would leave): the pose a
        # marker fewer gives is not the check's doing (pig_walk's left foot, whose heel the subject fits 19 mm RMS,
        # turns its ankle 50 deg on its toe marker alone)
        gapped = tmp / f"gapped{i}.c3d"
        write_c3d(gapped, Trial(trial.labels, unseen_instead(trial.markers, X, kind), trial.rate, 0, gapped.name))
        try:
            ref = ik(gapped)
            got = ik(path)
        except Exception as e:  # noqa: BLE001 - any failure is the finding
            row["outcome"] = f"{type(e).__name__}: {e}"
        else:
            # a frame's angle off both: the damage went into the pose (a check that leaves a position in keeps the
            # undamaged pose where the damage is small: 8 mm of noise at a stretch's end)
            diff = np.degrees(np.fmin(np.abs(got - ref), np.abs(got - undamaged)))
            f, c = np.unravel_index(int(np.nanargmax(diff)), diff.shape)
            over = int(np.sum(np.any(diff > tol_deg, axis=1)))
            row.update(max_deg=round(float(diff[f, c]), 1), worst=names[c], frame=int(f), frames_over=over,
                       from_undamaged_deg=round(float(np.degrees(np.nanmax(np.abs(got - undamaged)))), 1))
            bad = [f"{names[c]} {diff[f, c]:.1f} deg off at frame {f}; {over} frames over {tol_deg:g}"] if over else []
            row["outcome"] = "; ".join(bad) if bad else "ok"
        rows.append(row)
        if row["outcome"] != "ok":
            findings.append(row)
        print(f"  {i:3d} {kind:9s} {row['outcome'][:70]:70s} | from undamaged {row.get('from_undamaged_deg', '-')} "
              f"deg | {what[:70]}", flush=True)
    counts: dict[str, int] = {}
    for r in rows:
        key = f"{r['kind']}: {'ok' if r['outcome'] == 'ok' else 'finding'}"
        counts[key] = counts.get(key, 0) + 1
    return {"trial": "walk", "ik": True, "frames": trial.n_frames, "seed": seed, "tol_deg": tol_deg,
            "counts": counts, "findings": findings, "copies": rows}


def _kinds(text: str) -> list[str]:
    """--kinds' value: known kinds, comma-separated."""
    kinds = [k for k in text.split(",") if k]
    for k in kinds:
        if k not in KINDS + EXTRA_KINDS:
            raise argparse.ArgumentTypeError(f"unknown kind {k}; use {', '.join(KINDS + EXTRA_KINDS)}")
    return kinds


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--case", choices=tuple(CASES), default="pig_walk",
                    help="the real trials and base model (default pig_walk on models/human.urdf)")
    ap.add_argument("--trial", choices=("walk", "static"), default="walk", help="the case's trial to damage")
    ap.add_argument("--frames", type=int, default=300, help="its first N frames")
    ap.add_argument("--n", type=int, default=30, help="damaged copies")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--kinds", type=_kinds, default=list(KINDS),
                    help=f"comma-separated, of {', '.join(KINDS + EXTRA_KINDS)} (default: all but the last)")
    ap.add_argument("--tol-mm", type=float, default=10.0, help="largest joint-centre shift that passes (mm)")
    ap.add_argument("--ik", action="store_true", help="damage the trials `calibrate ik` fits (the walk)")
    ap.add_argument("--tol-deg", type=float, default=10.0,
                    help="with --ik: the largest change of a joint angle that passes (deg)")
    ap.add_argument("--json", type=Path, help="write the results here")
    a = ap.parse_args()
    if a.ik and a.case != "pig_walk":
        print("damage_values: --ik damages pig_walk's walk only; leave out --case", file=sys.stderr)
        return 2
    for f in CASES[a.case][2:]:
        if not f.exists():
            print(f"damage_values: {f}: not found; the real trials live in ../shared/data/real", file=sys.stderr)
            return 2
    out = run_ik(a.frames, a.n, a.seed, a.kinds, a.tol_deg) if a.ik else \
        run(a.trial, a.frames, a.n, a.seed, a.kinds, a.tol_mm, a.case)
    print(", ".join(f"{v} {k}" for k, v in sorted(out["counts"].items())))
    if a.json:
        a.json.write_text(json.dumps(out, indent=1))
    return 1 if out["findings"] else 0


if __name__ == "__main__":
    sys.exit(main())
