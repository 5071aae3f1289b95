r"""The project's one error family and its one-line formatter.

Every error the project raises on purpose is a :class:`DamperHilError`.  Its
:class:`UserError` branch is for what the user can fix — bad data, parameters, options, a
bag or a CAN bus that cannot be used — and says so in one line; the command line prints that
line and exits 2.  A :class:`DamperHilError` that is not a user error is a failure of the
environment (a node that never became ready, a peer that went silent): one line, exit 1.
Anything else reaching the command line is a bug in damper-hil (or in a library it calls):
it exits 1 with a short message, and ``--debug`` shows the traceback.

``UserError`` is also a :class:`ValueError`, so code written against the earlier
``ValueError`` subclasses (``ParameterError``, ``MeasuredDataError``, …) keeps working.

Names from the operating system that are not UTF-8 (a folder ``café`` named in Latin-1)
reach Python as strings with lone surrogates (PEP 383).  They stay so inside the program, where
the system needs them back; text meant for people or for other programs escapes them as
``\xNN``, the byte each stands for: :func:`printable`, and the :data:`ESCAPE` error handler
for text encoded to UTF-8 (files, the terminal).

This module imports nothing from the project: every layer may use it.
"""

from __future__ import annotations

import codecs

__all__ = ["ESCAPE", "DamperHilError", "UserError", "one_line", "printable"]

#: The codec error handler that writes a lone surrogate ``\udcNN`` (a byte of a name that
#: is not UTF-8) as the text ``\xNN``, and any other unencodable character as Python's
#: ``\uNNNN`` escape: ``text.encode("utf-8", ESCAPE)``.
ESCAPE = "damper-hil-escape"


def _escape(error: UnicodeError) -> tuple[str, int]:
    if not isinstance(error, UnicodeEncodeError):
        raise error
    bad = error.object[error.start:error.end]
    return "".join(f"\\x{ord(c) - 0xDC00:02x}" if 0xDC80 <= ord(c) <= 0xDCFF
                   else c.encode("unicode_escape").decode("ascii")
                   for c in bad), error.end


codecs.register_error(ESCAPE, _escape)


def printable(text: str) -> str:
    r"""``text`` with lone surrogates (bytes of a name that is not UTF-8) written as
    ``\xNN``: always encodable as UTF-8."""
    return text.encode("utf-8", ESCAPE).decode("utf-8")


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
    text = printable(" ".join(str(what).split()))
    if isinstance(what, BaseException):
        name = type(what).__name__
        if not text:
            return name
        return f"{name}: {text}" if with_type else text
    return text or "unknown error"
