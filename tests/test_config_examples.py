"""The settings examples the documentation shows are valid settings files that say what they claim."""

from __future__ import annotations

import math
import re
from pathlib import Path

from calibrate.io import config
from calibrate.io.config import load_settings

ROOT = Path(__file__).resolve().parents[1]


def _docs_example() -> str:
    """The TOML block of docs/calibration.md that shows every setting."""
    text = (ROOT / "docs" / "calibration.md").read_text()
    blocks = re.findall(r"```toml\n(.*?)```", text, flags=re.S)
    return next(b for b in blocks if "[marker_noise_mm]" in b)


def _module_example() -> str:
    """The example in calibrate.io.config's docstring (indented by four spaces)."""
    doc = config.__doc__
    body = doc.split("::", 1)[1]
    return "\n".join(line[4:] for line in body.splitlines())


def test_docs_example_reads_as_documented(tmp_path):
    path = tmp_path / "calib.toml"
    path.write_text(_docs_example())
    s = load_settings(path)
    # hold_axes and auto_hold are top-level settings, not marker noises (a past bug put them under a table)
    assert s.hold_axes == ()
    assert s.auto_hold is True
    assert dict(s.marker_noise) == {"LTHI": 0.003, "RTHI": 0.003}
    assert dict(s.lock) == {"subtalar_l": 0.0, "subtalar_r": 0.0}
    assert math.isclose(s.priors.axis, math.radians(10.0))


def test_module_example_reads_as_documented(tmp_path):
    path = tmp_path / "calib.toml"
    path.write_text(_module_example())
    s = load_settings(path)
    assert s.hold_axes == () and s.auto_hold is True
    assert dict(s.marker_noise) == {}
    assert math.isclose(s.priors.centre, 0.020) and math.isclose(s.priors.symmetry_scale, 0.05)
