"""The package works after ``pip install``: example trials and ``py.typed`` in the wheel.

The example trials stay in the repository's top-level ``data/``; ``pyproject.toml`` maps
that folder onto the data-only subpackage ``bayesbeam.examples``, so a wheel installs
them as ``bayesbeam/examples`` and :func:`bayesbeam.jobs.demo.find_data` finds them from
any working directory (``data/`` itself in a source checkout or an editable install).
"""

from __future__ import annotations

import fnmatch
import importlib.util
import os
import shutil
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest

import bayesbeam
import bayesbeam.jobs.demo as demo
from bayesbeam.jobs.demo import DATA_DIR, find_data, list_trials

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = Path(bayesbeam.__file__).resolve().parent
DATA = ROOT / "data"

#: Files of data/ that must reach the wheel: 15 trials (TOML + CSV), truth.toml, README.md.
N_SHIPPED = 32

#: What pip prints when it cannot reach a package index (no network, no mirror).
_OFFLINE = ("No matching distribution found", "Could not find a version that satisfies",
            "NewConnectionError", "Failed to establish a new connection",
            "Temporary failure in name resolution", "Network is unreachable")


def _setuptools_config() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["tool"][
        "setuptools"]


def _shipped_names(globs: list[str]) -> list[str]:
    return sorted(p.name for p in DATA.iterdir()
                  if p.is_file() and any(fnmatch.fnmatch(p.name, g) for g in globs))


def test_setuptools_lists_every_subpackage_and_ships_data_as_examples():
    cfg = _setuptools_config()
    # The package list is written out (a find cannot see the mapped data folder): a new
    # subpackage missing from it would be left out of the wheel.
    subpackages = {".".join(p.parent.relative_to(PACKAGE.parent).parts)
                   for p in PACKAGE.rglob("__init__.py")}
    assert subpackages, "no subpackages found: wrong PACKAGE folder"
    assert set(cfg["packages"]) == subpackages | {"bayesbeam.examples"}
    assert cfg["package-dir"] == {"bayesbeam.examples": "data"}
    assert cfg["package-data"]["bayesbeam"] == ["py.typed"]
    # Every file in data/ is shipped: the globs leave none out.
    globs = cfg["package-data"]["bayesbeam.examples"]
    every = sorted(p.name for p in DATA.iterdir() if p.is_file())
    assert _shipped_names(globs) == every
    assert len(every) == N_SHIPPED


def test_find_data_from_another_working_directory(tmp_path, monkeypatch):
    # In this process: the default is an absolute folder, whatever the working directory.
    monkeypatch.chdir(tmp_path)
    assert DATA_DIR.is_absolute()
    assert find_data() == DATA_DIR and (DATA_DIR / "truth.toml").is_file()
    assert len(list_trials()) == 15
    # A fresh interpreter started in an empty folder (DATA_DIR is set at import time):
    # the package under test first on its path, as an installed package would be.
    code = ("from bayesbeam.jobs.demo import find_data, list_trials; "
            "print(find_data()); print(len(list_trials()))")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(PACKAGE.parent),
                                                        os.environ.get("PYTHONPATH", "")])}
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, check=True,
                         capture_output=True, text=True, timeout=120).stdout.splitlines()
    assert Path(out[0]) == DATA_DIR and out[1] == "15"


def test_find_data_names_the_folder_it_looked_in(tmp_path, monkeypatch):
    monkeypatch.setattr(demo, "DATA_DIR", tmp_path / "gone")
    with pytest.raises(demo.DemoError, match="reinstall bayesbeam, or pass --data DIR"):
        demo.find_data()
    with pytest.raises(demo.DemoError, match="pass --data DIR with a folder of trial files"):
        demo.find_data(tmp_path)  # exists, but holds no trial


def _build_wheel(src: Path, out: Path) -> Path:
    """Build the wheel of ``src`` into ``out``; skip when that needs a network there is not."""
    cmd = [sys.executable, "-m", "pip", "wheel", "--no-deps", "-w", str(out), str(src)]
    # With setuptools installed the build needs no index (offline); without it pip fetches
    # setuptools into an isolated build environment, which needs the network.
    offline = importlib.util.find_spec("setuptools") is not None
    if offline:
        cmd.insert(4, "--no-build-isolation")
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    log = run.stdout + run.stderr
    if run.returncode != 0 and not offline and any(s in log for s in _OFFLINE):
        pytest.skip("cannot build a wheel here: setuptools is not installed and pip cannot "
                    "reach an index to fetch it (offline)")
    assert run.returncode == 0, log[-3000:]
    (wheel,) = out.glob("bayesbeam-*.whl")
    return wheel


@pytest.mark.slow
def test_wheel_ships_the_example_trials_and_py_typed(tmp_path):
    # Build from a copy of the sources, so no build/ or egg-info lands in the repository.
    src = tmp_path / "src"
    junk = shutil.ignore_patterns("__pycache__", "*.pyc", "*.egg-info")
    src.mkdir()
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        shutil.copy2(ROOT / name, src / name)
    shutil.copytree(PACKAGE, src / "bayesbeam", ignore=junk)
    shutil.copytree(DATA, src / "data", ignore=junk)
    wheel = _build_wheel(src, tmp_path / "dist")

    names = set(zipfile.ZipFile(wheel).namelist())
    assert "bayesbeam/py.typed" in names
    shipped = {n for n in names if n.startswith("bayesbeam/examples/")}
    assert shipped == {f"bayesbeam/examples/{p.name}" for p in DATA.iterdir() if p.is_file()}
    assert len(shipped) == N_SHIPPED
    assert not any(n.startswith(("data/", "studies/", "tests/")) for n in names)

    # Installed into a folder of its own and run from an empty working directory: the
    # example trials come from the installed package, not from this checkout.
    target, work = tmp_path / "site", tmp_path / "work"
    work.mkdir()
    subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "--no-index",
                    "--target", str(target), str(wheel)],
                   check=True, capture_output=True, text=True, timeout=300)
    env = {**os.environ, "PYTHONPATH": str(target)}
    code = ("import bayesbeam; from bayesbeam.jobs.demo import find_data, list_trials; "
            "print(bayesbeam.__file__); print(find_data()); print(len(list_trials()))")
    out = subprocess.run([sys.executable, "-c", code], cwd=work, env=env, check=True,
                         capture_output=True, text=True, timeout=120).stdout.splitlines()
    assert Path(out[0]).is_relative_to(target), out[0]
    assert Path(out[1]) == target / "bayesbeam" / "examples"
    assert out[2] == "15"
    version = subprocess.run([sys.executable, "-m", "bayesbeam", "--version"], cwd=work,
                             env=env, check=True, capture_output=True, text=True,
                             timeout=120).stdout
    assert version.strip() == f"bayesbeam {bayesbeam.__version__}"
