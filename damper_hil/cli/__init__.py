"""The ``damper-hil`` command line (docs/interfaces.md §3): one module per subcommand
(``add_parser`` and ``run``), :mod:`.common` for what they share.

Every user error (:class:`~damper_emulator.errors.UserError`: a bad parameter file, bad
measured data, a bad option value, a bag or bus that cannot be used; or an output that
cannot be written) is one line ``damper-hil: error: <message>`` on stderr and exit status 2;
anything else is a bug, reported in one line with exit status 1 (``--debug``: the
traceback).  Subcommands: ``damper-hil --help`` and docs/interfaces.md §3.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
from collections.abc import Sequence

from damper_emulator.errors import ESCAPE, DamperHilError, UserError, one_line
from damper_hil.cli import (
    bridge,
    demo,
    diagnose,
    dyno,
    dyno_demo,
    emulate,
    fleet,
    fleet_example,
    hybrid,
    identify,
    live,
    record,
    replay,
    ride,
    ride_study,
    skyhook,
    tune,
    validate,
    virtual_rig,
)
from damper_hil.cli.common import PROG

#: the subcommands, in the order ``--help`` lists them
SUBCOMMANDS = (dyno, demo, dyno_demo, emulate, ride, record, bridge, skyhook, replay,
               validate, identify, diagnose, ride_study, fleet, fleet_example, tune, live,
               hybrid, virtual_rig)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Hardware-in-the-loop damper emulator: Simms & Crolla hysteretic "
                    "mono-tube model, virtual dyno, identification and ride simulation.")
    from damper_emulator import __version__
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    parser.add_argument("--debug", action="store_true",
                        help="show the traceback of any error (also after the subcommand)")
    sub = parser.add_subparsers(dest="command", metavar="SUBCOMMAND", required=True)

    # ---- dyno ------------------------------------------------------------------------
    for module in SUBCOMMANDS:
        module.add_parser(sub)
    return parser


#: Set by :func:`main` when the command that ran leaves without the interpreter's
#: finalisation (:func:`entry`): its parser's ``hard_exit`` default.
_hard_exit = False


class Terminated(BaseException):
    """SIGTERM arrived (:func:`_terminated`): unwinds like ``KeyboardInterrupt``, past
    ``except Exception``, through every ``finally``; exit 143."""


def _terminated(signum: int, frame: object) -> None:
    raise Terminated

#: Printed under an unexpected exception (a bug, not a user error).
BUG_HINT = "run again with --debug for the traceback, and please report it"


def _debug_flag(argv: list[str]) -> tuple[list[str], bool]:
    """``argv`` without ``--debug`` (anywhere before ``--ros-args``) and whether it was
    there: the flag works before or after the subcommand."""
    head = argv[:argv.index("--ros-args")] if "--ros-args" in argv else argv
    if "--debug" not in head:
        return argv, False
    return [a for a in head if a != "--debug"] + argv[len(head):], True


def _escape_terminal() -> None:
    r"""Names that are not UTF-8 (lone surrogates, PEP 383) print as ``\xNN`` on stdout
    and stderr instead of stopping the command (:data:`~damper_emulator.errors.ESCAPE`)."""
    for stream in (sys.stdout, sys.stderr):
        reconfigure = getattr(stream, "reconfigure", None)
        if reconfigure is not None:
            # a stream that cannot change its errors keeps them
            with contextlib.suppress(ValueError, OSError):
                reconfigure(errors=ESCAPE)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status.

    0 success; 2 a user error (:class:`~damper_emulator.errors.UserError`: bad data,
    parameters, options, bag or bus; or an ``OSError`` on a file or device), one line;
    1 a failure that is not the input's (a node that never became ready: one line) or a bug
    (any other exception: one line and a hint; ``--debug`` shows the traceback); 130
    interrupted (Ctrl-C); 143 terminated (SIGTERM).
    """
    _escape_terminal()
    parser = build_parser()
    argv, debug = _debug_flag(list(sys.argv[1:] if argv is None else argv))
    ros_args: list[str] = []
    if "--ros-args" in argv:  # rclpy's own arguments, for the node subcommands
        i = argv.index("--ros-args")
        argv, ros_args = argv[:i], argv[i + 1:]
    args = parser.parse_args(argv)  # usage errors: argparse prints usage, exits 2
    args.ros_args = ros_args
    if ros_args and not getattr(args, "takes_ros_args", False):
        parser.error(f"{args.command} does not take --ros-args")
    # SIGTERM (a kill, a service manager's stop) ends a command as Ctrl-C does: its
    # cleanup runs (a demo stops its nodes, a run closes its recording); a command or
    # node that handles it itself installs its own handler later
    signal.signal(signal.SIGTERM, _terminated)
    try:
        status = args.handler(args)
        global _hard_exit
        _hard_exit = bool(getattr(args, "hard_exit", False))
        return status
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130
    except Terminated:
        print(f"{PROG}: terminated", file=sys.stderr)
        return 128 + signal.SIGTERM
    except Exception as exc:
        if debug:
            raise
        if isinstance(exc, UserError):
            print(f"{PROG}: error: {one_line(exc)}", file=sys.stderr)
            return 2
        if isinstance(exc, OSError):
            where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
            print(f"{PROG}: error: {one_line(where + (exc.strerror or str(exc)))}",
                  file=sys.stderr)
            return 2
        if isinstance(exc, DamperHilError):
            print(f"{PROG}: error: {one_line(exc)}", file=sys.stderr)
            return 1
        print(f"{PROG}: internal error: {one_line(exc, with_type=True)}\n"
              f"{PROG}: this is a bug in damper-hil, not in your input; {BUG_HINT}",
              file=sys.stderr)
        return 1


def entry() -> None:
    """The ``damper-hil`` console script: :func:`main`'s status as the exit status.

    A subcommand that holds nothing the interpreter's clean-up must close once it has
    returned (its files written and closed, no threads, processes or nodes left; its
    parser's ``hard_exit`` default: ``replay``) leaves through :func:`os._exit` after the
    streams are flushed, as mypy does: the finalisation of numba's, matplotlib's and
    rosbags' objects took 0.4 s of the 2.5 s a replay took in all, measured here.
    """
    status = main()
    if _hard_exit:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(status)
    sys.exit(status)
