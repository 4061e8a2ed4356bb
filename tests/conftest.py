"""Shared fixtures: the bundled model, its kinematics, and short simulated trials."""

from __future__ import annotations

from pathlib import Path

import pytest

from calibrate.kinematics import build_kinematics
from calibrate.model import load_model

ROOT = Path(__file__).resolve().parent.parent
HUMAN = ROOT / "models" / "human.urdf"


@pytest.fixture(scope="session")
def human():
    return load_model(HUMAN)


@pytest.fixture(scope="session")
def human_kin(human):
    return build_kinematics(human)
