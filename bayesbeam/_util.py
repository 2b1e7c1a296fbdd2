"""Private helpers below every layer of the package (standard library only at import).

* :func:`distribution_version`: the installed version of a distribution, or
  ``"0+unknown"`` when it is not installed (``bayesbeam.__version__`` and the
  provenance records);
* :func:`lazy_exports`: the PEP 562 ``__getattr__`` / ``__dir__`` pair with which
  ``bayesbeam`` and its subpackages expose their public names without importing every
  module at ``import bayesbeam``;

* :func:`json_default`: the ``default=`` hook of :func:`json.dumps` for numpy scalars
  and arrays, paths, mappings, sets and tuples (used by :mod:`bayesbeam.inference.results` and
  :mod:`bayesbeam.jobs.executor`);
* :func:`finite_json`: a copy of a record with non-finite floats replaced by ``None``
  so that it can be written as strict JSON (used by :mod:`bayesbeam.jobs.executor` and
  :mod:`bayesbeam.jobs.demo`).

Only the standard library is imported at import time (numpy when a value needs it).
This module imports nothing from bayesbeam: every layer may use it.
"""

from __future__ import annotations

import dataclasses
import importlib
import importlib.metadata
import math
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

__all__ = ["distribution_version", "finite_json", "json_default", "lazy_exports"]


def distribution_version(dist: str, missing: str = "0+unknown") -> str:
    """Installed version of a distribution.

    Parameters
    ----------
    dist : str
        Distribution name, e.g. ``"bayesbeam"`` or ``"numpy"``.
    missing : str, optional
        What to return when it is not installed (a source tree run without
        ``pip install``).

    Returns
    -------
    str
        Its version, or ``missing``.
    """
    try:
        return importlib.metadata.version(dist)
    except importlib.metadata.PackageNotFoundError:
        return missing


def lazy_exports(
    package: str, exports: Mapping[str, str]
) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """Build a package's ``__getattr__`` and ``__dir__`` importing names on first use (PEP 562).

    Parameters
    ----------
    package : str
        The importing package's ``__name__``.
    exports : mapping of str to str
        Public name -> module that defines it, relative to ``package`` (``".fit"``)
        or absolute.

    Returns
    -------
    getattr, dir : callable
        To assign to the package's ``__getattr__`` and ``__dir__``.
    """

    def __getattr__(name: str) -> Any:
        try:
            module = exports[name]
        except KeyError:
            raise AttributeError(f"module {package!r} has no attribute {name!r}") from None
        return getattr(importlib.import_module(module, package), name)

    def __dir__() -> list[str]:
        return sorted(set(exports) | set(vars(importlib.import_module(package))))

    return __getattr__, __dir__


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
