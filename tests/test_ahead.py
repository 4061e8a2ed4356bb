"""run_ahead: an iterator's values made in a forked child process (the other core) are the values the
caller would have made; the child's failure is raised in the caller; a child no longer needed is stopped;
and a calibration gives the same bits with its work run ahead as without."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import calibrate.calibration.start as start
from calibrate.calibration.pipeline import calibrate
from calibrate.io.trial import Trial
from calibrate.model.kinematics import build_kinematics
from calibrate.model.model import load_model
from calibrate.problem.settings import Settings
from calibrate.simulation.simulate import simulate_squats
from calibrate.solve.ahead import can_run_ahead, idle_core, run_ahead
from calibrate.solve.assembly import WORKER_NAME, worker_thread

forks = pytest.mark.skipif(not can_run_ahead(), reason="run_ahead forks only on Linux with two or more cores")


def _values(n: int):
    for k in range(n):
        yield k, os.getpid(), worker_thread(), np.linalg.cholesky(np.eye(3) * (k + 1.5) + 0.1)


@forks
def test_values_are_made_in_a_child_in_order_and_equal_the_callers():
    got = list(run_ahead(_values(3)))
    here = list(_values(3))
    assert [g[0] for g in got] == [0, 1, 2]
    assert all(g[1] != os.getpid() for g in got)  # another process made them ...
    assert all(g[2] for g in got)  # ... as a worker: its parallel parts run one after another
    assert not here[0][2]
    for g, h in zip(got, here, strict=True):
        np.testing.assert_array_equal(g[3], h[3])


def _fails():
    yield 1
    raise ValueError("marker RASI: no frames")


@forks
def test_the_childs_exception_is_raised_at_the_value_that_raised_it():
    values = run_ahead(_fails())
    assert next(values) == 1
    with pytest.raises(ValueError, match="marker RASI: no frames"):
        next(values)
    assert list(values) == []  # ended


def _forever():
    yield os.getpid()
    while True:
        time.sleep(0.05)


@forks
def test_closing_early_stops_and_reaps_the_child():
    values = run_ahead(_forever())
    pid = next(values)
    values.close()
    with pytest.raises(ProcessLookupError):  # killed and reaped: no such process left
        os.kill(pid, 0)


def test_from_a_worker_the_iterator_is_kept_as_it_is():
    gen = _values(1)
    out = {}
    t = threading.Thread(target=lambda: out.setdefault("it", run_ahead(gen)), name=f"{WORKER_NAME}-test")
    t.start()
    t.join()
    assert out["it"] is gen


def _two_trials(human, seed: int) -> list[Trial]:
    """Two 90-frame trials of one simulated subject: the two halves of one squat trial (simulate_squats draws a
    new subject for every seed, and two subjects calibrated as one take several times as long to settle)."""
    one = simulate_squats(human, frames=180, noise_mm=1.0, seed=seed).trial
    return [Trial(one.labels, one.markers[a:a + 90], one.rate, one.first_frame + a, None) for a in (0, 90)]


@forks
def test_calibration_is_the_same_with_its_work_run_ahead(monkeypatch):
    """Two trials (every second trial's start poses in a child) and a stated noise no start fits (so both
    candidates of the start's race are solved, the second in a child, a core taken as idle whatever the other
    tests running beside this one do): the same start, the same bits as with Settings.ahead off, where
    everything runs in this process."""
    human = load_model(Path(__file__).resolve().parents[1] / "models" / "human.urdf")
    kin = build_kinematics(human)
    trials = _two_trials(human, seed=31)
    raced = []
    monkeypatch.setattr(start, "idle_core", lambda: True)
    monkeypatch.setattr(start, "run_ahead", lambda values: raced.append(1) or run_ahead(values))
    ahead = calibrate(human, trials, Settings(noise=0.0005), kinematics=kin)
    assert raced == [1]  # the race's second candidate was solved in a child
    here = calibrate(human, trials, Settings(noise=0.0005, ahead=False), kinematics=kin)
    race = [n for n in ahead.seed.notes if n.startswith("started from")]
    assert race == [n for n in here.seed.notes if n.startswith("started from")]
    assert race[0].count("(cost") == 2  # both candidates solved
    np.testing.assert_array_equal(ahead.initial_residuals, here.initial_residuals)
    np.testing.assert_array_equal(ahead.params.vector(), here.params.vector())



@pytest.mark.skipif(not Path("/proc/stat").exists(), reason="idle_core reads Linux's /proc/stat")
def test_no_core_is_idle_while_every_core_runs_a_task():
    """With a spinning process on every core this process may use, idle_core says no core is idle (the start's
    race then solves its second candidate here, not on a guess in a child)."""
    spin = "import time\nt = time.time()\nwhile time.time() - t < 5:\n    pass\n"
    procs = [subprocess.Popen([sys.executable, "-c", spin]) for _ in os.sched_getaffinity(0)]
    try:
        time.sleep(0.5)
        seen = [idle_core() for _ in range(5)]
    finally:
        for proc in procs:
            proc.kill()
            proc.wait()
    assert not any(seen), seen

def test_ahead_is_a_setting_of_the_settings_file(tmp_path):
    from calibrate.io.config import load_settings

    f = tmp_path / "calib.toml"
    f.write_text("ahead = false\n")
    assert load_settings(f).pipeline.ahead is False
    assert Settings().pipeline.ahead is True
    with pytest.raises(ValueError, match="ahead: must be true or false"):
        Settings(ahead="no")


def test_the_command_line_gives_the_same_bits_in_every_fresh_process(tmp_path):
    """Two trials calibrated by the command line twice, each time in a fresh process (the start's work run
    ahead in a child, the worker threads, every library loaded afresh): the written subject model and
    motions are byte for byte the same.  A change that makes the arithmetic depend on thread timing shows
    here.  (Not every such change: a lazy import made gait2392's result vary from run to run, on a path
    these squats do not take; docs/benchmarks.md.)"""
    import subprocess
    import sys

    from calibrate.io.c3d import write_c3d

    human_path = Path(__file__).resolve().parents[1] / "models" / "human.urdf"
    human = load_model(human_path)
    for s, trial in zip((41, 42), _two_trials(human, seed=41), strict=True):
        write_c3d(tmp_path / f"t{s}.c3d", trial)
    written = []
    for run in ("a", "b"):
        out = tmp_path / run
        out.mkdir()
        r = subprocess.run([sys.executable, "-m", "calibrate.cli", str(tmp_path / "t41.c3d"), str(tmp_path / "t42.c3d"),
                            str(human_path), "-o", str(out / "subject.urdf"), "-q"], capture_output=True, text=True,
                           cwd=out, timeout=300)
        assert r.returncode == 0, r.stderr
        written.append({p.name: p.read_bytes() for p in sorted(out.iterdir()) if p.suffix in (".urdf", ".csv")})
    assert set(written[0]) == {"subject.urdf", "t41_motion.csv", "t42_motion.csv"}
    assert written[0] == written[1]
