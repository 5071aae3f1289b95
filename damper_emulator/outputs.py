r"""Writing a command's outputs so that nothing half-written is ever left in their place.

Each output is written into a temporary sibling (``.<stem>.partial-<pid><suffix>``, in the same
folder, so on the same file system) and renamed into place once the command has finished.
Outputs that belong together, :class:`Outputs` (a report folder, a parameter file and its
JSON, the fleet's tables and summary), are renamed together at the end, with SIGINT and
SIGTERM held back meanwhile.  A run that fails or is interrupted before that leaves the
previous result whole, or nothing; its temporary siblings are removed (or, after a
SIGKILL, by the next run).  The renames protect against an interrupted process, not against
a power cut (nothing is ``fsync``-ed).

A folder output is replaced as a whole, so that no file of an earlier run survives beside
the new ones: where the system has ``renameat2(RENAME_EXCHANGE)`` (Linux) the old and the
new folder swap in one step, otherwise the old one is moved aside first.  Only a folder this
module wrote (it carries a :data:`MARKER` file), or an empty one, is replaced: any other
folder that exists is refused before the work starts, naming it.

The output locations are checked when they are registered, before the work: a parent that
cannot be created, a file where a folder is wanted (or the reverse), a folder that is not
writable or not the project's is one :class:`OutputError` line.

Names and paths stay as the operating system gives them (a name that is not UTF-8 holds lone
surrogates, PEP 383).  Text the project writes escapes them as ``\xNN``, the bytes they
stand for (the :data:`~damper_emulator.errors.ESCAPE` error handler and
:func:`~damper_emulator.errors.printable`), so a folder named ``café`` in
Latin-1 is a row ``caf\xe9``, not a crash.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import re
import shutil
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from types import TracebackType

from damper_emulator.errors import ESCAPE, UserError
from damper_emulator.signals import signals_held

__all__ = ["MARKER", "OutputError", "Outputs", "atomic_path", "write_bytes", "write_text"]

#: The file that marks a folder as written by this module (its content says so).
MARKER = ".damper-hil-output"
_MARKER_TEXT = "written by damper-hil: replaced as a whole by the next run\n"
#: ``renameat2`` flag: exchange the two paths atomically (linux/fs.h)
_RENAME_EXCHANGE = 2
_AT_FDCWD = -100


class OutputError(UserError):
    """An output location cannot be written (one line naming it)."""


def _staging(target: Path, pid: int | str | None = None) -> Path:
    """``.<stem>.partial-<pid><suffix>``: hidden, beside ``target``, with its suffix (which
    tells writers such as matplotlib the format)."""
    return target.with_name(f".{target.stem}.partial-{os.getpid() if pid is None else pid}"
                            f"{target.suffix}")


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()


def _remove_stale(target: Path) -> None:
    """Temporary siblings of ``target`` left by a process that no longer runs."""
    pattern = re.compile(re.escape(str(_staging(target, "@"))).replace("@", r"(\d+)") + "$")
    try:
        entries = list(target.parent.iterdir())
    except OSError:
        return
    for entry in entries:
        match = pattern.match(str(entry))
        if match and int(match[1]) != os.getpid() and not _alive(int(match[1])):
            _remove(entry)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _make_parent(target: Path) -> None:
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise OutputError(f"{target}: cannot write: {target.parent} is not a folder") from None
    except OSError as exc:
        raise OutputError(f"{target}: cannot create the folder {target.parent}: "
                          f"{exc.strerror or exc}") from None


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """The path to write ``path`` at (a temporary sibling with the same suffix), renamed
    into place when the block ends without an exception, removed when it raises: a reader
    sees the old file or the new one, never part of one.

    Raises
    ------
    OutputError
        The file cannot be written (one line naming it).
    """
    path = Path(path)
    _make_parent(path)
    tmp = _staging(path)
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException as exc:
        _remove(tmp)
        if isinstance(exc, OSError):
            raise OutputError(f"{path}: cannot write: {exc.strerror or exc}") from None
        raise


def write_bytes(path: str | os.PathLike[str], data: bytes) -> Path:
    """Write ``data`` to ``path`` at once (:func:`atomic_path`).  Returns ``path``."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def write_text(path: str | os.PathLike[str], text: str) -> Path:
    r""":func:`write_bytes` of ``text`` in UTF-8, lone surrogates (names that are not UTF-8)
    escaped as ``\xNN``.  Returns ``path``."""
    return write_bytes(path, text.encode("utf-8", ESCAPE))


def _exchange(a: Path, b: Path) -> bool:
    """Swap two existing paths in one step (Linux ``renameat2``); False where the system
    cannot."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        renameat2 = libc.renameat2
    except (OSError, AttributeError):
        return False
    renameat2.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p,
                          ctypes.c_uint]
    renameat2.restype = ctypes.c_int
    status: int = renameat2(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b),
                            _RENAME_EXCHANGE)
    return status == 0


def _contents(folder: Path, shown: int = 6) -> str:
    """``/ (3 files: a.png, b.png, c.md)`` for a message."""
    names = sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*")
                   if p.is_file() and p.name != MARKER)
    listed = ", ".join(names[:shown]) + (", ..." if len(names) > shown else "")
    return f"/ ({len(names)} file{'s' if len(names) != 1 else ''}: {listed})"


def _new_folder(path: Path) -> None:
    """An empty folder output at ``path``, with the marker that says damper-hil wrote it."""
    path.mkdir()
    (path / MARKER).write_text(_MARKER_TEXT, encoding="utf-8")


def _key(path: Path) -> Path:
    return Path(os.path.abspath(path))


class Outputs:
    """A set of outputs written together (module docstring).

    Register each output before the work with :meth:`file` or :meth:`folder` (a folder
    before any file inside it), which check the location and return where to write it
    meanwhile; on leaving the ``with`` block
    without an exception every output is renamed into place (:meth:`commit`), otherwise
    the temporary copies are removed (:meth:`discard`).

    Parameters
    ----------
    say : callable, optional
        Told ``wrote <path>`` for each output once it is in place.
    inputs : paths, optional
        What the command reads: an output that is one of them, or a folder output that
        holds one, is refused (replacing it would destroy the input, or make the results
        name a file that no longer holds what was read).

    Examples
    --------
    >>> with Outputs() as out:                              # doctest: +SKIP
    ...     params = out.file(Path("fitted.yaml"))
    ...     report = out.folder(Path("report"))
    ...     ...                                             # the work, then:
    ...     save_config(cfg, params)
    ...     plot(report / "fit.png")
    """

    def __init__(self, say: Callable[[str], None] | None = None,
                 inputs: Iterable[str | os.PathLike[str] | None] = ()) -> None:
        self._say = say
        self._inputs = {Path(p): _key(Path(p)) for p in inputs if p is not None}
        #: target → staging, in the order registered
        self._files: dict[Path, Path] = {}
        self._folders: dict[Path, Path] = {}
        #: each target as the caller named it (for messages)
        self._given: dict[Path, Path] = {}
        self._done = False

    # ---- registering ----------------------------------------------------------------

    def _inside(self, target: Path) -> Path | None:
        """Where ``target`` goes when it lies in a registered folder."""
        key = _key(target)
        for folder, staging in self._folders.items():
            if key != folder and key.is_relative_to(folder):
                return staging / key.relative_to(folder)
        return None

    def _check_new(self, target: Path, folder: bool) -> None:
        key = _key(target)
        if key in self._files or key in self._folders:
            raise OutputError(f"{target}: given as two outputs")
        for given, source in self._inputs.items():
            if source == key:
                raise OutputError(f"{target}: is also an input; write the output elsewhere")
            if folder and source.is_relative_to(key):
                raise OutputError(f"{target}: holds the input {given} and is replaced as a "
                                  "whole; choose another output folder")

    def file(self, target: str | os.PathLike[str]) -> Path:
        """Register the file ``target``; returns the path to write it at meanwhile.

        Raises
        ------
        OutputError
            ``target`` is a folder, or its folder cannot be created or written.
        """
        target = Path(target)
        self._check_new(target, folder=False)
        if target.is_dir():
            raise OutputError(f"{target}: is a folder (expected a file name)")
        inside = self._inside(target)
        if inside is not None:
            inside.parent.mkdir(parents=True, exist_ok=True)
            return inside
        return self._stage(target, self._files, lambda staging: staging.write_bytes(b""))

    def folder(self, target: str | os.PathLike[str]) -> Path:
        """Register the folder ``target`` (replaced as a whole); returns the folder to
        write into meanwhile.

        Raises
        ------
        OutputError
            ``target`` is a file; or a folder that holds files not written by damper-hil
            (it is not replaced: give a new or empty folder); or its parent cannot be
            created or written.
        """
        target = Path(target)
        self._check_new(target, folder=True)
        if target.exists() and not target.is_dir():
            raise OutputError(f"{target}: is a file (expected a folder)")
        inner = [self._given[k] for k in self._files if k.is_relative_to(_key(target))]
        if inner:   # its path, already handed out, would be outside the staged folder
            raise RuntimeError(f"bug: the folder output {target} is registered after the "
                               f"file output {inner[0]} inside it")
        if target.is_dir():
            try:
                entries = [e.name for e in target.iterdir()]
            except OSError as exc:
                raise OutputError(f"{target}: cannot read the folder: "
                                  f"{exc.strerror or exc}") from None
            if entries and MARKER not in entries:
                raise OutputError(
                    f"{target}: the folder holds files damper-hil did not write "
                    f"({', '.join(sorted(entries)[:3])}{', ...' if len(entries) > 3 else ''}"
                    "); it is replaced as a whole, so give a new or empty folder")
        inside = self._inside(target)
        if inside is not None:
            inside.mkdir(parents=True, exist_ok=True)
            return inside
        return self._stage(target, self._folders, _new_folder)

    def _stage(self, target: Path, into: dict[Path, Path],
               make: Callable[[Path], object]) -> Path:
        """Make ``target``'s temporary sibling with ``make`` (which proves the place
        writable) and register it in ``into``."""
        _make_parent(target)
        _remove_stale(target)
        staging = _staging(target)
        _remove(staging)
        try:
            make(staging)
        except OSError as exc:
            raise OutputError(f"{target}: cannot write in {target.parent}: "
                              f"{exc.strerror or exc}") from None
        into[_key(target)] = staging
        self._given[_key(target)] = target
        return staging

    def final(self, path: str | os.PathLike[str]) -> Path:
        """The place ``path`` (a path returned by :meth:`file` or :meth:`folder`, or one
        inside such a folder) will have once the outputs are in place."""
        key = _key(Path(path))
        for target, staging in (*self._files.items(), *self._folders.items()):
            if key == _key(staging):
                return self._given[target]
            if key.is_relative_to(_key(staging)):
                return self._given[target] / key.relative_to(_key(staging))
        return Path(path)

    # ---- finishing ------------------------------------------------------------------

    def commit(self) -> list[Path]:
        """Rename every output into place (SIGINT and SIGTERM held back meanwhile);
        returns the targets, and tells ``say`` of each."""
        if self._done:
            return []
        done: list[Path] = []
        with signals_held():
            for target, staging in self._files.items():
                os.replace(staging, target)
                done.append(target)
            for target, staging in self._folders.items():
                if target.is_dir():
                    if _exchange(staging, target):
                        _remove(staging)          # now the old folder
                    else:
                        old = _staging(target, f"{os.getpid()}-old")
                        os.rename(target, old)
                        os.rename(staging, target)
                        _remove(old)
                else:
                    os.rename(staging, target)
                done.append(target)
            self._done = True
        if self._say is not None:
            for target in done:
                self._say(f"wrote {self._given[target]}"
                          + (_contents(target) if target.is_dir() else ""))
        return [self._given[target] for target in done]

    def discard(self) -> None:
        """Remove every temporary copy; the previous outputs stay as they were."""
        if self._done:
            return
        for staging in (*self._files.values(), *self._folders.values()):
            _remove(staging)
        self._done = True

    def __enter__(self) -> Outputs:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if exc_type is None:
            self.commit()
        else:
            self.discard()
