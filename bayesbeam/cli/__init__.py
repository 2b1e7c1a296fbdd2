"""The command line ``bayesbeam COMMAND``.

The command line ``bayesbeam COMMAND``: the entry point :func:`bayesbeam.cli.main.main`,
one module per sub-command (:mod:`~bayesbeam.cli.fit`, :mod:`~bayesbeam.cli.compare`, ...)
and the options they share (:mod:`~bayesbeam.cli.options`).

Layer: the top; nothing in the package imports it.
"""

__all__: list[str] = []
