"""Errors that reach the user as one clear line.

Every error thermonet raises for bad user input is a :class:`ThermonetError`
(a ``ValueError``), whose message names the file, the column or key, and the
row where it applies.  The CLI prints ``str(err)`` and exits with status 1.
"""

from __future__ import annotations

__all__ = ["ThermonetError", "InputError", "ConfigError", "FitError", "ExportError",
           "Interrupted", "first_line", "failures_line", "counted"]


def first_line(err: BaseException) -> str:
    """What a caught error says, in one line: its message's first line, else its type's name
    (a library's error quoted inside thermonet's own one-line message)."""
    return str(err).splitlines()[0] if str(err) else type(err).__name__


def counted(k: int, word: str) -> str:
    """``k`` and ``word``, plural unless ``k`` is 1 ("1 flight", "3 flights")."""
    return f"{k} {word}{'s' * (k != 1)}"


def failures_line(bad: list[tuple[str, str]], what: str, shown: int = 5) -> str:
    """One line for several items that failed, ``bad`` = (name, reason): items failing for
    the same reason are named once ("4 units ('u000', 'u001', …): measured …"; a reason's own
    "<what> '<name>': " prefix is taken off to compare), at most ``shown`` reasons."""
    groups: dict[str, list[str]] = {}
    for name, reason in bad:
        own = f"{what} '{name}': "
        groups.setdefault(reason[len(own):] if reason.startswith(own) else reason,
                          []).append(name)
    parts = []
    for reason, names in list(groups.items())[:shown]:
        who = (f"{what} '{names[0]}'" if len(names) == 1 else f"{len(names)} {what}s (" +
               ", ".join(f"'{n}'" for n in names[:2]) + (", …)" if len(names) > 2 else ")"))
        parts.append(f"{who}: {reason}")
    more = len(groups) - shown
    return "; ".join(parts) + (f" (and {more} more reasons)" if more > 0 else "")


class ThermonetError(ValueError):
    """Base class of every user-facing error; its message is one line."""

    def __init__(self, message: str) -> None:
        super().__init__(" ".join(str(message).split()))


class InputError(ThermonetError):
    """A recording or mapping file that cannot be read as a thermal test."""

    @classmethod
    def at(cls, source: object, message: str, *, column: str | None = None,
           row: int | None = None) -> InputError:
        """Build ``"<source>: column 'x', row 12: message"``."""
        where = [str(source)] if source else []
        if column is not None:
            where.append(f"column '{column}'")
        if row is not None:
            where.append(f"row {row}")
        return cls(", ".join(where) + ": " + message if where else message)


class ConfigError(ThermonetError):
    """A configuration file with an unknown key, a wrong type or a bad value."""


class FitError(ThermonetError):
    """A model family that cannot be fitted on the given data (reason in the message)."""


class ExportError(ThermonetError):
    """An export that was refused (NaN model, failed parity check, wrong family)."""


class Interrupted(BaseException):
    """SIGINT/SIGTERM reached a command: unwinds like ``KeyboardInterrupt`` (not an error).

    A ``BaseException`` so that no ``except Exception`` swallows it; the CLI
    prints one line and exits ``128 + signum`` (130 for SIGINT, 143 for
    SIGTERM); open MLflow runs are ended as KILLED on the way out.
    """

    def __init__(self, signum: int) -> None:
        import signal

        super().__init__(signal.Signals(signum).name)
        self.signum = signum


#: Signals received and not yet acted on (:func:`request_interrupt`): a signal handler's
#: exception can be swallowed when it lands inside a garbage-collection callback ("Exception
#: ignored in ..."), so long loops also poll this flag (:func:`check_interrupted`).
_PENDING_SIGNALS: list[int] = []


def request_interrupt(signum: int) -> None:
    """Record that SIGINT/SIGTERM arrived (the CLI's handler calls this, then raises)."""
    _PENDING_SIGNALS.append(int(signum))


def clear_interrupt() -> None:
    """Forget recorded signals (at the start and end of a command)."""
    _PENDING_SIGNALS.clear()


def check_interrupted() -> None:
    """Raise :class:`Interrupted` when a signal arrived and its exception was lost on the
    way (called once per training epoch)."""
    if _PENDING_SIGNALS:
        raise Interrupted(_PENDING_SIGNALS[0])

