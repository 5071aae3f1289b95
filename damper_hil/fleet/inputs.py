"""A fleet's inputs: one subfolder of ``DATA_DIR`` per damper (docs/fleet.md).

In each subfolder, measured-data files (CONTRACT "Measured-data files") named by protocol:

* ``quasi_static*.csv``: identification, quasi-static fit (one or more);
* ``chirp*.csv``: identification, valve fit (one or more);
* ``sine_*.csv``: validation (held out; at least one);

each also as ``.csv.gz``, ``.tdms``, ``.mf4`` or ``.mdf`` (read through a ``columns.yaml``
beside them where the folder has one); and an optional ``base.yaml``, the damper's data sheet
(geometry, γ, ν, α and numerics, as ``identify --base``; default ``config/sport.yaml``).
Other files are ignored.  The subfolder's name is the damper's id.
"""

from __future__ import annotations

import fnmatch
from dataclasses import dataclass
from pathlib import Path

from damper_emulator.dyno.measured_bag import data_stem
from damper_emulator.errors import UserError

#: file-name patterns of each role (lower case), before the measured-data suffix
#: (:data:`~damper_emulator.dyno.measured_bag.DATA_SUFFIXES`: ``.csv``, ``.csv.gz``, ...)
ROLES = {"quasi_static": "quasi_static*", "chirp": "chirp*", "validate": "sine_*"}
#: the data sheet's file name in a damper's folder
BASE_FILE = "base.yaml"


@dataclass(frozen=True)
class DamperInputs:
    """One damper's test set: its id and its files by role (sorted by name)."""

    id: str
    folder: Path
    quasi_static: tuple[Path, ...]
    chirp: tuple[Path, ...]
    validate: tuple[Path, ...]
    base: Path | None

    def problem(self) -> str | None:
        """Why this test set cannot be used (one line), or ``None``."""
        missing = [f"{role} ({ROLES[role]}.csv)" for role in ROLES if not getattr(self, role)]
        if missing:
            return f"{self.folder}: no {' and no '.join(missing)} file"
        return None


def _role_of(name: str) -> str | None:
    stem = data_stem(name)
    if stem is None:
        return None
    low = stem.lower()
    for role, pattern in ROLES.items():
        if fnmatch.fnmatchcase(low, pattern):
            return role
    return None


def find_dampers(data_dir: Path) -> list[DamperInputs]:
    """Every subfolder of ``data_dir`` (hidden ones excepted), sorted by name.

    Raises
    ------
    UserError
        ``data_dir`` is not a folder, or has no subfolder.
    """
    if not data_dir.is_dir():
        raise UserError(f"{data_dir}: not a folder (expected one subfolder per damper)")
    out = []
    for folder in sorted(p for p in data_dir.iterdir()
                         if p.is_dir() and not p.name.startswith(".")):
        files: dict[str, list[Path]] = {role: [] for role in ROLES}
        for f in sorted(folder.iterdir()):
            role = _role_of(f.name) if f.is_file() else None
            if role is not None:
                files[role].append(f)
        base = folder / BASE_FILE
        out.append(DamperInputs(folder.name, folder, *(tuple(files[r]) for r in ROLES),
                                base if base.is_file() else None))
    if not out:
        raise UserError(f"{data_dir}: no damper subfolders (expected one per damper, each "
                        f"with {', '.join(p + '.csv' for p in ROLES.values())} files)")
    return out
