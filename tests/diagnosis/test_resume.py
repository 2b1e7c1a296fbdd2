"""The step store of a resumable diagnosis (``bayesbeam.diagnosis.resume``)."""

import numpy as np

from bayesbeam.diagnosis.resume import StepStore, step_key


def test_key_follows_every_input_to_the_last_bit():
    ctx = {"seed": 0, "data_sha256": "ab"}
    u = np.array([0.1, -2.0, 3.5])
    k = step_key(ctx, model="viscous", u=u, seed=7)
    assert k == step_key(dict(ctx), seed=7, u=u.copy(), model="viscous")  # order-free
    assert k != step_key(ctx, model="viscous", u=np.nextafter(u, 1.0), seed=7)
    assert k != step_key(ctx, model="viscous", u=u, seed=8)
    assert k != step_key({**ctx, "seed": 1}, model="viscous", u=u, seed=7)
    assert k != step_key(ctx, model="viscous", u=u.astype(np.float32), seed=7)
    assert step_key(ctx, u=None) != step_key(ctx, u=np.zeros(0))


def test_store_round_trip_and_what_counts_as_absent(tmp_path):
    folder = tmp_path / "steps"
    st = StepStore(folder, {"seed": 0}, read=True)
    key = st.key(model="m", u=np.arange(3.0))
    assert st.get("map", key) is None  # nothing yet
    st.put("map", key, (np.arange(3.0), 1.5, -2.0))
    u, lp, ll = st.get("map", key)
    np.testing.assert_array_equal(u, np.arange(3.0))
    assert (lp, ll, st.hits) == (1.5, -2.0, 1)
    assert st.get("fit", key) is None  # another kind of step
    # A file cut short (a kill while writing elsewhere) is absent, not an error.
    path = next(folder.glob("map-*.pkl"))
    path.write_bytes(path.read_bytes()[:10])
    assert st.get("map", key) is None
    # Another run without resume empties the folder first.
    st.put("map", key, 1.0)
    StepStore(folder, {"seed": 0}, read=False)
    assert not folder.exists()
    # A store that does not read never returns a step.
    st2 = StepStore(folder, {"seed": 0}, read=False)
    st2.put("map", key, 1.0)
    assert st2.get("map", key) is None
