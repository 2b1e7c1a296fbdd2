"""The MAP searches' results kept beside the sampler checkpoint, for resumed fits.

A fit spends its first minutes (on whole records: several) on the MAP search and the
mesh check before the sampler starts; the sampler's checkpoint (``chain.h5``) keeps what
comes after. Without this file an interrupted fit that is resumed repeats the search to
reach the same start. :class:`MapCache` writes each search's result (the point, its log
posterior, the mesh record and the random generator's state after it) to
``OUTDIR/map.json`` as it is found, and a resumed fit takes it from there instead:
restoring the generator's state makes the resumed run take the very decisions an
uninterrupted one takes.

An entry is used only when the run's fingerprint (model, data, seed, priors, options)
is the one it was written under and the log posterior at the stored point, evaluated
again on the stored mesh, equals the stored value (to 1e-9 relative): a file from
other code or other options is ignored and the search runs again, saying so.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from bayesbeam._util import json_default, write_text_atomic

__all__ = ["FILE", "MapCache", "fingerprint", "restore_rng"]

#: The file in a fit's output folder.
FILE = "map.json"

#: Relative agreement of the re-evaluated log posterior with the stored one (rounding
#: of the same evaluation in another process is ~1e-13 of it; a code or data change
#: moves it far more).
LP_RTOL = 1e-9


def fingerprint(parts: Mapping[str, Any]) -> str:
    """SHA-256 of a run's identifying options, written as canonical JSON.

    Parameters
    ----------
    parts : mapping
        JSON-serialisable options (model, data hashes, seed, priors, mesh, ...).

    Returns
    -------
    str
        Hex digest.
    """
    text = json.dumps(parts, sort_keys=True, default=str)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


class MapCache:
    """MAP results of one run, read from and written to ``OUTDIR/map.json``.

    Parameters
    ----------
    outdir : path or None
        The fit's output folder; None keeps nothing (every call is a miss).
    key : str
        The run's :func:`fingerprint`.
    resume : bool
        False: a file there belongs to an earlier run and is deleted.
    say : callable, optional
        Called with one line when a stored entry is not used, and why.
    """

    def __init__(self, outdir: str | Path | None, key: str, *, resume: bool,
                 say: Callable[[str], None] | None = None) -> None:
        self.path = None if outdir is None else Path(outdir) / FILE
        self.key = key
        self._say = say
        self.entries: dict[str, dict[str, Any]] = {}
        if self.path is None:
            return
        if not resume:
            self.path.unlink(missing_ok=True)
            return
        if not self.path.is_file():
            return
        try:
            stored = json.loads(self.path.read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError) as exc:
            self._note(f"{self.path} cannot be read ({exc}); the MAP search runs again")
            return
        if not isinstance(stored, dict) or stored.get("key") != key:
            self._note(f"{self.path} belongs to a run with other options; the MAP search "
                       "runs again")
            return
        self.entries = dict(stored.get("entries", {}))

    def _note(self, msg: str) -> None:
        if self._say is not None:
            self._say(msg)

    def get(self, name: str, ndim: int,
            log_prob: Callable[[np.ndarray, Mapping[str, Any] | None], float],
            ) -> dict[str, Any] | None:
        """Return the stored result ``name`` if it still holds, else None.

        Parameters
        ----------
        name : str
            The search's name (``"map"``, ``"trial 2"``, ``"joint"``).
        ndim : int
            Dimension the point must have.
        log_prob : callable
            ``log_prob(u, mesh) -> float``: the log posterior at ``u`` (shape (ndim,)) of
            the problem on the stored mesh record, to check the stored value again.

        Returns
        -------
        dict or None
            ``u`` (ndarray, shape (ndim,)), ``lp`` (float), ``mesh`` (dict or None) and
            ``rng_state`` (the generator's state after the search, or None).
        """
        e = self.entries.get(name)
        if e is None:
            return None
        u = np.asarray(e.get("u", []), dtype=float)
        lp = float(e.get("lp", np.nan))
        if u.shape != (ndim,) or not np.isfinite(lp):
            self._note(f"the stored MAP {name!r} does not fit this problem; searching again")
            return None
        lp_now = float(log_prob(u, e.get("mesh")))
        if not abs(lp_now - lp) <= LP_RTOL * max(1.0, abs(lp)):
            self._note(f"the stored MAP {name!r} has log posterior {lp:.10g} but "
                       f"{lp_now:.10g} now (other code or data); searching again")
            return None
        return {"u": u, "lp": lp, "mesh": e.get("mesh"), "rng_state": e.get("rng_state")}

    def recall(self, name: str, ndim: int,
               log_prob: Callable[[np.ndarray, Mapping[str, Any] | None], float],
               search: Callable[[], tuple[np.ndarray, float, Mapping[str, Any] | None]],
               rng: np.random.Generator) -> tuple[np.ndarray, float, Any, bool]:
        """Return the stored result ``name`` where it holds (restoring ``rng``), else search.

        Parameters
        ----------
        name, ndim, log_prob
            As for :meth:`get`.
        search : callable
            ``search() -> (u, lp, mesh)``, drawing from ``rng``; its result is stored.
        rng : numpy.random.Generator
            The run's generator: restored on a hit, its state stored after a search.

        Returns
        -------
        u : ndarray, shape (ndim,)
        lp : float
        mesh : dict or None
        recalled : bool
            Whether the result came from the file.
        """
        hit = self.get(name, ndim, log_prob)
        if hit is not None:
            restore_rng(rng, hit["rng_state"])
            return hit["u"], hit["lp"], hit["mesh"], True
        u, lp, mesh = search()
        self.put(name, u, lp, mesh=mesh, rng=rng)
        return u, lp, mesh, False

    def put(self, name: str, u: np.ndarray, lp: float, *, mesh: Mapping[str, Any] | None = None,
            rng: np.random.Generator | None = None) -> None:
        """Store a search's result (the file is rewritten atomically).

        Parameters
        ----------
        name : str
        u : ndarray, shape (ndim,)
            The point, in the sampling space.
        lp : float
            Its log posterior.
        mesh : mapping, optional
            The mesh record (:func:`~bayesbeam.inference.mesh.converge_mesh`).
        rng : numpy.random.Generator, optional
            The generator whose state after the search a resumed run restores.
        """
        self.entries[name] = {
            "u": [float(x) for x in np.asarray(u, dtype=float)],
            "lp": float(lp),
            "mesh": None if mesh is None else json.loads(json.dumps(mesh, default=json_default)),
            "rng_state": None if rng is None else rng.bit_generator.state,
        }
        if self.path is not None:
            self.path.parent.mkdir(parents=True, exist_ok=True)  # before the sampler makes it
            write_text_atomic(self.path, json.dumps({"key": self.key, "entries": self.entries},
                                                    default=json_default) + "\n")


def restore_rng(rng: np.random.Generator, state: Mapping[str, Any] | None) -> None:
    """Set ``rng`` to a stored state (no-op for None or another generator kind).

    Parameters
    ----------
    rng : numpy.random.Generator
    state : mapping or None
        ``bit_generator.state`` as stored by :meth:`MapCache.put`.
    """
    if state is not None and state.get("bit_generator") == rng.bit_generator.state[
            "bit_generator"]:
        rng.bit_generator.state = dict(state)

