"""Exception hierarchy of pgdcli.

Every error pgdcli raises on purpose derives from :class:`PgdError`, and its
``str()`` is a single line that names the file, key or option at fault and what
was expected. The command line prints it as ``Error: <message>`` and exits with
status 2; anything else escaping is a bug.
"""

from __future__ import annotations


class PgdError(Exception):
    """Base class of every pgdcli error (one-line message)."""


class SpecError(PgdError):
    """Invalid problem specification (YAML file, key, value or expression)."""


class ExpressionError(SpecError):
    """An expression that cannot be parsed, is not allowed, or is not separable."""


class CodebookError(PgdError):
    """A file that is not a readable codebook of a supported version."""


class QueryError(PgdError):
    """Invalid evaluation request: unknown, missing or out-of-domain coordinates."""


class SolverError(PgdError):
    """The solver cannot run on the given problem (not raised for non-convergence)."""


class VerifyError(PgdError):
    """Invalid verification request (options, points file)."""


class LimitError(PgdError):
    """Work or input beyond a documented limit (:mod:`pgdcli.limits`), refused before it starts."""


class TimeBudgetExceeded(PgdError):
    """A check or picture stopped at its time budget (``--max-seconds``): exit status 1, not 2."""


class ClusterError(PgdError):
    """A Dask cluster that cannot be used: unreachable, without workers, or lost during the work."""
