"""The ``pgd`` command line: the click group with every command registered.

``pgdcli.cli.main.cli`` is the click group (:mod:`pgdcli.cli.group`); importing this module
registers the commands, one module each. The console script starts in :mod:`pgdcli.cli.entry`.
"""

from __future__ import annotations

from . import fit_command, info_command, plot_command, query_command, solve_command, verify_command  # noqa: F401
from . import sensitivity_command, view_command  # noqa: F401
from .group import cli

__all__ = ["cli"]
