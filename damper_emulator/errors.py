"""The project's one error family and its one-line formatter.

Every error the project raises on purpose is a :class:`DamperHilError`.  Its
:class:`UserError` branch is for what the user can fix — bad data, parameters, options, a
bag or a CAN bus that cannot be used — and says so in one line; the command line prints that
line and exits 2.  A :class:`DamperHilError` that is not a user error is a failure of the
environment (a node that never became ready, a peer that went silent): one line, exit 1.
Anything else reaching the command line is a bug in damper-hil (or in a library it calls):
it exits 1 with a short message, and ``--debug`` shows the traceback.

``UserError`` is also a :class:`ValueError`, so code written against the earlier
``ValueError`` subclasses (``ParameterError``, ``MeasuredDataError``, …) keeps working.

This module imports nothing from the project: every layer may use it.
"""

from __future__ import annotations

__all__ = ["DamperHilError", "UserError", "one_line"]


class DamperHilError(Exception):
    """Base of every error damper-hil raises on purpose."""


class UserError(DamperHilError, ValueError):
    """Input the user can fix (data, parameters, options, bag, bus); one line."""


def one_line(what: BaseException | str, with_type: bool = False) -> str:
    """``what``'s message on one line (whitespace collapsed).

    Parameters
    ----------
    what : BaseException or str
    with_type : bool
        Prefix the exception's class name (for a third-party error wrapped in ours, whose
        class tells what failed).  An exception without a message is its class name.
    """
    text = " ".join(str(what).split())
    if isinstance(what, BaseException):
        name = type(what).__name__
        if not text:
            return name
        return f"{name}: {text}" if with_type else text
    return text or "unknown error"
