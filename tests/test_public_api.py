"""The public face: ``bayesbeam`` and each subpackage export their names lazily."""

import importlib
import inspect
import subprocess
import sys

import pytest

import bayesbeam

SUBPACKAGES = ["physics", "stats", "trials", "inference", "comparison", "diagnosis",
               "report", "jobs", "cli"]


def test_import_bayesbeam_loads_no_heavy_dependency():
    # A fresh interpreter: the lazy face must not import numpy, scipy, emcee or arviz.
    code = ("import sys, bayesbeam; "
            "print(sorted(m for m in ('numpy', 'scipy', 'emcee', 'arviz', 'matplotlib') "
            "if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "[]"


@pytest.mark.parametrize("name", sorted(set(bayesbeam.__all__) - {"__version__"}))
def test_top_level_names_resolve(name):
    obj = getattr(bayesbeam, name)
    assert obj.__module__ == bayesbeam._EXPORTS[name]
    assert name in dir(bayesbeam)


@pytest.mark.parametrize("sub", SUBPACKAGES)
def test_subpackage_names_come_from_their_defining_module(sub):
    pkg = importlib.import_module(f"bayesbeam.{sub}")
    exports = getattr(pkg, "_EXPORTS", {})
    assert sorted(exports) == pkg.__all__
    for name, module in exports.items():
        mod = importlib.import_module(module, pkg.__name__)
        obj = getattr(pkg, name)
        assert obj is getattr(mod, name)
        # defined there, not re-exported from another module
        if inspect.isclass(obj) or inspect.isfunction(obj):
            assert obj.__module__ == mod.__name__, (name, obj.__module__, mod.__name__)


def test_unknown_name_is_a_clear_attribute_error():
    with pytest.raises(AttributeError, match="module 'bayesbeam' has no attribute 'fitt'"):
        bayesbeam.fitt  # noqa: B018
