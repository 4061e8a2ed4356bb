"""The public API (issue 19): the top level exports what a user needs, each sub-package its own names,
resolved from the module that defines them."""

import importlib

import calibrate

SUBPACKAGES = ("io", "model", "seed", "problem", "solve", "calibration", "simulation")


def test_top_level_is_small_and_complete():
    assert len(calibrate.__all__) <= 16
    for name in ("load_model", "write_model", "Model", "Parameters", "read_trial", "Trial", "Motion", "calibrate",
                 "Calibration", "Settings", "Priors", "CalibrateError", "ModelError", "TrialError"):
        assert name in calibrate.__all__ and getattr(calibrate, name) is not None


def test_subpackage_exports_resolve_to_their_definitions():
    for sub in SUBPACKAGES:
        pkg = importlib.import_module(f"calibrate.{sub}")
        assert pkg.__all__ and sorted(pkg.__all__) == pkg.__dir__()
        for name in pkg.__all__:
            obj = getattr(pkg, name)
            home = getattr(obj, "__module__", None)
            if home is not None and home.startswith("calibrate"):
                assert home.startswith(f"calibrate.{sub}."), (sub, name, home)
                assert getattr(importlib.import_module(home), name) is obj
        missing = "no_such_name"
        try:
            getattr(pkg, missing)
        except AttributeError as exc:
            assert "no_such_name" in str(exc)
        else:  # pragma: no cover
            raise AssertionError("an unknown name must raise AttributeError")
