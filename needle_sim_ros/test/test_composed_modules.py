"""Where the composed runs' generated modules are written (model/step.py): numba's cache directory, else the user's
cache, else the temporary directory, so that a read-only home does not stop the compiled run."""
import importlib
import os
import tempfile

import numba

step = importlib.import_module("needle_sim_ros.model.step")  # the package exports a function of that name


def test_an_unwritable_cache_and_home_fall_back_to_the_temporary_directory(tmp_path, monkeypatch):
    blocked = tmp_path / "a_file"
    blocked.write_text("")  # a folder below a file cannot be made (also as root, unlike a read-only mode)
    monkeypatch.setattr(numba.config, "CACHE_DIR", str(blocked / "numba"))
    monkeypatch.setenv("HOME", str(blocked / "home"))
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))
    path = step._written("needle_composed_test", "VALUE = 1\n")
    assert path == tmp_path / "tmp" / f"needle_sim-{os.getuid()}" / "composed" / "needle_composed_test.py"
    assert path.read_text() == "VALUE = 1\n"
    assert step._written("needle_composed_test", "VALUE = 1\n") == path  # found again, not rewritten


def test_numbas_cache_directory_comes_first(tmp_path, monkeypatch):
    monkeypatch.setattr(numba.config, "CACHE_DIR", str(tmp_path / "numba"))
    path = step._written("needle_composed_test", "VALUE = 2\n")
    assert path == tmp_path / "numba" / "composed" / "needle_composed_test.py"
