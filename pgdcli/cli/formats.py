"""The output formats of the commands: one registry per command, one writer per format.

``pgd query``, ``pgd fit``, ``pgd info``, ``pgd verify``, ``pgd solve`` and ``pgd sensitivity`` take
``--format NAME``. Each command has a :class:`Formats` here; each format is a writer registered on it
where the writer is defined (``@QUERY.register("csv", "...")``). The choices click offers, the names the lean
``pgd query`` parser accepts, the option's help and the writer a name runs are all read from that
registry: a format is added by registering its writer, and a name without a writer can be neither
offered nor run (no branch of an ``if`` to miss). No click and no numpy (the lean query path
imports this module).
"""

from __future__ import annotations

from typing import Callable

__all__ = ["Formats", "QUERY", "FIT", "INFO", "VERIFY", "SOLVE", "SENSITIVITY"]


class Formats:
    """The output formats of one command, in the order they were registered.

    Parameters
    ----------
    command : str
        The command's name (in messages).
    default : str
        The format used without ``--format`` (registered like any other).
    """

    def __init__(self, command: str, default: str):
        self.command = command
        self.default = default
        self._writers: dict[str, object] = {}
        self._help: dict[str, str] = {}

    def register(self, name: str, help: str) -> Callable:
        """Decorator: register the writer (a function or class) of format ``name``, described by ``help``."""
        def decorate(writer):
            if name in self._writers:
                raise ValueError(f"pgd {self.command}: output format {name!r} registered twice")
            self._writers[name] = writer
            self._help[name] = help
            return writer

        return decorate

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self._writers)

    def help(self) -> str:
        """``name: what it writes`` for every format, as the ``--format`` option's help."""
        return "; ".join(f"{name}: {text}" for name, text in self._help.items()) + "."

    def writer(self, name: str):
        """The writer of format ``name``; ValueError (naming the formats there are) for any other name."""
        try:
            return self._writers[name]
        except KeyError:
            raise ValueError(f"pgd {self.command}: no output format {name!r}; expected one of "
                             f"{', '.join(self.names)}") from None


QUERY = Formats("query", "plain")
FIT = Formats("fit", "plain")
INFO = Formats("info", "text")
VERIFY = Formats("verify", "text")
SOLVE = Formats("solve", "text")
SENSITIVITY = Formats("sensitivity", "plain")
