"""JSON conversion helpers shared by the result writers.

* :func:`json_default`: the ``default=`` hook of :func:`json.dumps` for numpy scalars
  and arrays, paths, mappings, sets and tuples (used by :mod:`bayesbeam.results` and
  :mod:`bayesbeam.executor`);
* :func:`finite_json`: a copy of a record with non-finite floats replaced by ``None``
  so that it can be written as strict JSON (used by :mod:`bayesbeam.executor` and
  :mod:`bayesbeam.demo`).

Only the standard library is imported at import time (numpy when a value needs it).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

__all__ = ["finite_json", "json_default"]


def json_default(obj: Any) -> Any:
    """``json.dumps`` default: numpy scalars/arrays, paths and mappings to JSON types.

    Parameters
    ----------
    obj : object
        A value :mod:`json` cannot write by itself.

    Returns
    -------
    object
        A list (arrays, sets, tuples), a Python scalar (numpy scalars), a str (paths)
        or a dict (mappings).

    Raises
    ------
    TypeError
        For any other type; the message names it.
    """
    import numpy as np

    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    if isinstance(obj, Mapping):
        return dict(obj)
    if isinstance(obj, (set, frozenset, tuple)):
        return list(obj)
    raise TypeError(f"cannot write {type(obj).__name__} to JSON: {obj!r}")


def finite_json(obj: Any) -> Any:
    """Copy ``obj`` for strict JSON: non-finite floats become ``None``.

    Mapping keys become ``str``, tuples lists, dataclass instances dicts and paths
    ``str``; other values are kept as they are.

    Parameters
    ----------
    obj : object
        A record made of mappings, lists, tuples, dataclasses, paths and scalars.

    Returns
    -------
    object
        The converted copy.
    """
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, Mapping):
        return {str(k): finite_json(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_json(v) for v in obj]
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return finite_json(dataclasses.asdict(obj))
    if isinstance(obj, Path):
        return str(obj)
    return obj
