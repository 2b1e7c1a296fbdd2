"""MapCache: stored MAP results are used only where they still hold."""

from __future__ import annotations

import numpy as np
import pytest

from bayesbeam.inference.map_cache import FILE, MapCache, fingerprint, restore_rng


def _quadratic(u, mesh):
    return -0.5 * float(np.sum(np.asarray(u) ** 2))


@pytest.fixture
def stored(tmp_path):
    key = fingerprint({"model": "viscous", "seed": 3})
    rng = np.random.default_rng(7)
    rng.normal(size=5)  # the search's draws
    u = np.array([0.1, -0.2, 0.3])
    MapCache(tmp_path, key, resume=False).put("map", u, _quadratic(u, None),
                                              mesh={"n_elements": 16}, rng=rng)
    return key, u, rng


def test_round_trip_restores_point_mesh_and_generator(tmp_path, stored):
    key, u, rng = stored
    hit = MapCache(tmp_path, key, resume=True).get("map", 3, _quadratic)
    np.testing.assert_array_equal(hit["u"], u)  # JSON floats round-trip exactly
    assert hit["lp"] == _quadratic(u, None) and hit["mesh"] == {"n_elements": 16}
    fresh = np.random.default_rng(0)
    restore_rng(fresh, hit["rng_state"])
    np.testing.assert_array_equal(fresh.normal(size=4), rng.normal(size=4))


def test_other_options_or_other_values_are_not_used(tmp_path, stored):
    key, u, _ = stored
    said = []
    other = MapCache(tmp_path, fingerprint({"model": "viscous", "seed": 4}), resume=True,
                     say=said.append)
    assert other.get("map", 3, _quadratic) is None and "other options" in said[-1]
    same = MapCache(tmp_path, key, resume=True, say=said.append)
    assert same.get("map", 4, _quadratic) is None and "does not fit" in said[-1]
    # The density at the stored point changed (other code or data): searched again.
    assert same.get("map", 3, lambda v, m: _quadratic(v, m) + 1e-6) is None
    assert "searching again" in said[-1]
    assert same.get("trial 2", 3, _quadratic) is None  # never stored


def test_a_new_run_deletes_the_file_and_a_damaged_one_is_said(tmp_path, stored):
    key, _, _ = stored
    MapCache(tmp_path, key, resume=False)
    assert not (tmp_path / FILE).exists()
    (tmp_path / FILE).write_text("{not json", encoding="utf-8")
    said = []
    cache = MapCache(tmp_path, key, resume=True, say=said.append)
    assert cache.get("map", 3, _quadratic) is None and "cannot be read" in said[0]


def test_without_a_folder_nothing_is_kept():
    cache = MapCache(None, "k", resume=True)
    cache.put("map", np.zeros(2), 0.0)
    assert cache.path is None and cache.get("map", 2, _quadratic) is not None


def test_recall_searches_once_then_restores(tmp_path):
    calls = []

    def search(rng):
        calls.append(1)
        rng.normal(size=3)
        return np.array([0.5, 0.5]), _quadratic([0.5, 0.5], None), None

    first = np.random.default_rng(2)
    u, lp, _, recalled = MapCache(tmp_path, "k", resume=False).recall(
        "joint", 2, _quadratic, lambda: search(first), first)
    assert not recalled and len(calls) == 1
    again = np.random.default_rng(2)
    u2, lp2, _, recalled = MapCache(tmp_path, "k", resume=True).recall(
        "joint", 2, _quadratic, lambda: search(again), again)
    assert recalled and len(calls) == 1 and lp2 == lp
    np.testing.assert_array_equal(u2, u)
    np.testing.assert_array_equal(again.normal(size=2), first.normal(size=2))


def test_the_folder_is_made_when_missing(tmp_path):
    # A fit writes its MAP before the sampler creates the output folder.
    cache = MapCache(tmp_path / "new" / "viscous", "k", resume=False)
    cache.put("map", np.zeros(2), 0.0)
    assert (tmp_path / "new" / "viscous" / FILE).is_file()
