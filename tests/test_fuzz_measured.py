"""Property-based tests of the measured-data CSV reader (``damper_emulator.dyno.measured``).

A measured-data file comes from a dyno, a colleague or a download, so anything may be in
it.  Whatever its bytes, :func:`read_measured_csv` (and :func:`read_csv_table` below it)
must return the data or raise :class:`MeasuredDataError`, the one-line user error the
command line prints (exit 2): never another exception, never a hang.  A file it accepts
holds what its docstring promises (at least 2 rows of finite numbers, time strictly
increasing); an error names the file.

The files: CSV-like text made of random headers (the known columns in any case, with
blanks, twice, missing, other names), rows of random number spellings (huge, tiny, nan,
inf, hex, underscores, Unicode digits, quotes, empty fields, short rows), blank lines, a
BOM, CR LF or CR line ends, NUL, in UTF-8 or another encoding; random text; random bytes;
and gzip-compressed files (recognised by their magic bytes), whole, truncated or with
bytes changed.
"""

from __future__ import annotations

import gzip
import math

import numpy as np
import pytest
from fuzz_support import junk_bytes, junk_text, mutated_bytes, time_limit
from hypothesis import assume, example, given, settings
from hypothesis import strategies as st

from damper_emulator.dyno.measured import (
    OPTIONAL_COLUMNS,
    REQUIRED_COLUMNS,
    MeasuredData,
    MeasuredDataError,
    read_csv_table,
    read_measured_csv,
)

GZIP_MAGIC = b"\x1f\x8b"

#: Column names: the reader's own (in any case, with blanks), near misses and others.
column_names = st.one_of(
    st.sampled_from(REQUIRED_COLUMNS + OPTIONAL_COLUMNS),
    st.sampled_from(("Time", " DISPLACEMENT ", "Force\t", "velocity ", "temp", "x", "",
                     "time,force", '"time"', "\ufefftime", "name")),
    st.text(max_size=8),
)
#: Other columns of a dyno file, which the reader ignores.
other_names = st.sampled_from(("channel", "pressure", "x", "", "# comment", "Zeit", "1.5"))

#: A field: a number as people and programs write it, or something that is not one.
fields = st.one_of(
    st.floats(-1.0, 1.0).map(lambda x: f"{x:.9g}"),
    st.floats(-1e4, 1e4).map(lambda x: f"{x:.6g}"),
    st.floats().map(repr),  # nan, inf, 1e+308, 5e-324, -0.0
    st.integers(-10**30, 10**30).map(str),
    st.sampled_from(("nan", "NaN", "-inf", "Infinity", "1e999", "-1e999", "1e-400", "0x10",
                     "1_000", " 1 ", "", " ", '"1"', '"1,5"', "1,5", "--1", "+.5", ".",
                     "\u0663", "\u00a01", "1e", "e1", "1.0.0", "\x00", "1\x00", "TRUE")),
    st.text(max_size=6),
)


@st.composite
def plausible_rows(draw: st.DrawFn, columns: list[str]) -> list[list[str]]:
    """Rows a real dyno could have written for ``columns``: a sine stroke at 1 kHz with
    the force of a damper; most files of this kind read without error."""
    n = draw(st.integers(0, 40))
    amp = draw(st.floats(1e-4, 0.05))
    freq = draw(st.floats(0.5, 20.0))
    rows = []
    for i in range(n):
        t = i * 1e-3
        x = amp * math.sin(2 * math.pi * freq * t)
        v = amp * 2 * math.pi * freq * math.cos(2 * math.pi * freq * t)
        known = {"time": t, "displacement": x, "velocity": v, "force": 3000.0 * v + 50.0,
                 "temperature": 40.0}
        rows.append([f"{known.get(c.strip().lower(), 1.0):.9g}" for c in columns])
    return rows


@st.composite
def csv_texts(draw: st.DrawFn) -> str:
    """The text of a CSV-like file (see the module docstring)."""
    if draw(st.integers(0, 3)) == 0:
        columns = draw(st.lists(column_names, min_size=1, max_size=7))
    else:  # the right columns, in any order and case, and others: on to the rows
        known = [*REQUIRED_COLUMNS, *draw(st.lists(st.sampled_from(OPTIONAL_COLUMNS),
                                                   unique=True))]
        known = [draw(st.sampled_from((c, c.upper(), f" {c} ", c.title()))) for c in known]
        columns = draw(st.permutations(known + draw(st.lists(other_names, max_size=2))))
    rows = draw(plausible_rows(columns))
    for _ in range(draw(st.sampled_from((0, 0, 1, 2, 4)))):  # spoil fields or rows
        if rows:
            r = draw(st.integers(0, len(rows) - 1))
            if draw(st.booleans()):
                c = draw(st.integers(0, max(len(rows[r]) - 1, 0)))
                rows[r][c:c + 1] = [draw(fields)]
            else:
                rows[r] = draw(st.lists(fields, max_size=8))
    if draw(st.booleans()):
        rows += draw(st.lists(st.lists(fields, max_size=8), max_size=6))
    lines = [",".join(columns)] + [",".join(r) for r in rows]
    for _ in range(draw(st.integers(0, 2))):  # blank lines, or junk lines
        lines.insert(draw(st.integers(0, len(lines))),
                     draw(st.sampled_from(("", " ", ",,,", '"', '""', "#", "\x00"))
                          | junk_text.map(lambda s: s[:40])))
    end = draw(st.sampled_from(("\n", "\r\n", "\r")))
    text = end.join(lines) + draw(st.sampled_from(("", end, end * 2)))
    if draw(st.booleans()):
        text = "\ufeff" + text
    return text


@st.composite
def csv_files(draw: st.DrawFn) -> bytes:
    """A CSV-like text in some encoding, or random text, or random bytes; never gzip
    (those are :func:`gzip_files`)."""
    kind = draw(st.sampled_from(("csv", "csv", "csv", "text", "bytes")))
    if kind == "bytes":
        blob = draw(junk_bytes)
    else:
        text = draw(csv_texts() if kind == "csv" else junk_text)
        encoding = draw(st.sampled_from(("utf-8",) * 6 + ("utf-8-sig", "latin-1", "cp1252",
                                                          "utf-16", "utf-32")))
        blob = text.encode(encoding, errors="replace")
    assume(not blob.startswith(GZIP_MAGIC))
    return blob


@st.composite
def gzip_files(draw: st.DrawFn) -> bytes:
    """A gzip-compressed CSV-like file: whole, or truncated / with bytes changed; or the
    gzip magic bytes followed by junk."""
    if draw(st.integers(0, 4)) == 0:
        return GZIP_MAGIC + draw(junk_bytes)
    blob = gzip.compress(draw(csv_files()), mtime=0)
    if draw(st.booleans()):
        blob = draw(mutated_bytes(blob))
    return blob


def check_measured(path) -> MeasuredData | None:
    """Read ``path`` with :func:`read_measured_csv`; assert the outcome is the data as
    promised or a :class:`MeasuredDataError` naming the file."""
    try:
        with time_limit():
            data = read_measured_csv(path)
    except MeasuredDataError as exc:
        assert str(path) in str(exc)
        return None
    assert isinstance(data, MeasuredData)
    n = len(data)
    assert n >= 2
    for arr in (data.time, data.displacement, data.force, data.velocity, data.temperature):
        if arr is not None:
            assert arr.shape == (n,)
            assert np.isfinite(arr).all()
    assert (np.diff(data.time) > 0).all()
    return data


def check_table(path) -> None:
    """Read ``path`` with :func:`read_csv_table`, numeric (the fast path first) and with a
    text column (field by field); assert columns of the promised length or a
    :class:`MeasuredDataError` naming the file."""
    text_parser = {"name": lambda text, column, row, fail: text}
    for required, optional, parsers in ((REQUIRED_COLUMNS, OPTIONAL_COLUMNS, None),
                                        (("time",), ("name", "force"), text_parser)):
        try:
            with time_limit():
                table = read_csv_table(path, required, optional, parsers=parsers)
        except MeasuredDataError as exc:
            assert str(path) in str(exc)
            continue
        assert set(required) <= set(table.values)
        for column, values in table.values.items():
            assert len(values) == table.rows, column


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz_measured")


@given(blob=csv_files())
def test_measured_csv_any_text_or_bytes(workdir, blob):
    """Plain files: the data or MeasuredDataError."""
    path = workdir / "data.csv"
    path.write_bytes(blob)
    check_measured(path)
    check_table(path)


#: A gzip stream whose deflate data is damaged (a byte of its first block changed): the
#: one example the gzip test below always runs first: damaged deflate data, which raises
#: zlib.error (not an OSError) from the gzip stream.
DAMAGED_GZIP = bytearray(gzip.compress(b"time,displacement,force\n0,0,100\n0.001,0.001,200\n",
                                       mtime=0))
DAMAGED_GZIP[10] ^= 0xFF


@example(blob=bytes(DAMAGED_GZIP))
@given(blob=gzip_files())
def test_measured_csv_gzip(workdir, blob):
    """Gzip-compressed files (by magic bytes, whatever the name): the data or
    MeasuredDataError."""
    path = workdir / "data.csv.gz"
    path.write_bytes(blob)
    check_measured(path)
    check_table(path)


#: column names as labs write them, with units pint knows, does not know, or of another
#: dimension, and ISO-looking stamps among the fields
mapped_names = st.sampled_from(("Timestamp", "Force (N)", "Force_lbf", "force_kN",
                                "Position [in]", "Displacement (mm)", "Temp (F)",
                                "Temperature (C)", "x (furlong/s)", "F (blorts)", "t (ms)",
                                "F (m)", "v [mm/s]", "T [K]", "F ()", "F (1/0)", "F [**]",
                                "F ((N)", "F_(N", "F (N/0)", "F (1e5 N)", "F (-)"))
stamps = st.datetimes(allow_imaginary=False).map(lambda d: d.isoformat(" "))


@st.composite
def mapped_files(draw: st.DrawFn) -> tuple[bytes, dict[str, str]]:
    """A CSV-like file with lab column names, and a map of some of them."""
    names = draw(st.lists(mapped_names, min_size=1, max_size=5, unique=True))
    quantities = draw(st.permutations(["time", "displacement", "force", "velocity",
                                       "temperature"]))
    cmap = dict(zip(quantities, names))
    rows = [[draw(st.one_of(fields, stamps)) for _ in names]
            for _ in range(draw(st.integers(0, 8)))]
    text = "\n".join([",".join(names)] + [",".join(r) for r in rows])
    return text.encode("utf-8", errors="replace"), cmap


@given(file=mapped_files(), sign=st.sampled_from((1.0, -1.0)),
       zero=st.sampled_from(("file", "mid-stroke")),
       window=st.sampled_from((None, 5, 25)))
def test_mapped_csv_any_lab_file(workdir, file, sign, zero, window):
    """Through a column map (damper_emulator/dyno/column_map.py): the data or a one-line
    user error (MeasuredDataError, ColumnMapError), never another exception."""
    from damper_emulator.dyno.column_map import ColumnMap, read_mapped_csv

    blob, columns = file
    path = workdir / "lab.csv"
    path.write_bytes(blob)
    check_read(lambda: read_mapped_csv(path, ColumnMap(
        columns=columns, force_sign=sign, displacement_zero=zero, velocity_window=window)))


def check_read(read) -> None:
    """``read()`` (a reader of a lab file, through a column map) returns checked data or
    raises a one-line user error, within 10 s."""
    from damper_emulator.errors import UserError

    with time_limit(10):
        try:
            data = read()
        except UserError as exc:
            assert "\n" not in str(exc)
            return
    assert len(data) >= 2 and np.all(np.diff(data.time) > 0)
    assert np.isfinite(data.force).all() and np.isfinite(data.displacement).all()


def _valid_tdms() -> bytes:
    """A small TDMS file as nptdms writes it: a force and a displacement channel with a
    waveform time."""
    import io

    from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

    t = np.arange(50) / 100.0
    buffer = io.BytesIO()
    with TdmsWriter(buffer) as writer:
        writer.write_segment([RootObject(), GroupObject("g"), ChannelObject(
            "g", "force", 500.0 * np.cos(t), properties={"unit_string": "N",
                                                          "wf_increment": 0.01}),
            ChannelObject("g", "displacement", 0.01 * np.sin(t))])
    return buffer.getvalue()


@st.composite
def tdms_files(draw: st.DrawFn) -> bytes:
    """A TDMS file whole, damaged, or random bytes after the TDMS lead-in."""
    kind = draw(st.sampled_from(("mutated", "mutated", "whole", "junk")))
    if kind == "junk":
        return b"TDSm" + draw(junk_bytes)
    valid = _valid_tdms()
    return valid if kind == "whole" else draw(mutated_bytes(valid))


@given(blob=tdms_files())
def test_tdms_any_bytes(workdir, blob):
    """A TDMS file (damper_emulator/dyno/tdms.py): the data or a one-line user error."""
    pytest.importorskip("nptdms")
    from damper_emulator.dyno.column_map import ColumnMap
    from damper_emulator.dyno.tdms import read_mapped_tdms

    path = workdir / "data.tdms"
    path.write_bytes(blob)
    check_read(lambda: read_mapped_tdms(path, ColumnMap()))


def _valid_mf4() -> bytes:
    """A small MF4 file as asammdf writes it: a force and a displacement channel."""
    import tempfile
    from pathlib import Path

    from asammdf import MDF, Signal

    t = np.arange(50) / 100.0
    mdf = MDF(version="4.10")
    mdf.append([Signal(500.0 * np.cos(t), t, name="force", unit="N"),
                Signal(0.01 * np.sin(t), t, name="displacement", unit="m")])
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "valid.mf4"
        mdf.save(path, overwrite=True)
        mdf.close()
        return path.read_bytes()


@st.composite
def mf4_files(draw: st.DrawFn) -> bytes:
    """An MF4 file whole, damaged, or random bytes after the MDF lead-in."""
    kind = draw(st.sampled_from(("mutated", "mutated", "whole", "junk")))
    if kind == "junk":
        return b"MDF     4.10    " + draw(junk_bytes)
    valid = _valid_mf4()
    return valid if kind == "whole" else draw(mutated_bytes(valid))


#: each MDF read runs in a child process (asammdf segfaults on some damaged files), about
#: 2 s: a thirtieth of the profile's examples (2 in make test, 83 in make fuzz)
@settings(max_examples=max(2, settings.default.max_examples // 30))
@given(blob=mf4_files())
def test_mf4_any_bytes(workdir, blob):
    """An MDF file (damper_emulator/dyno/mdf.py): the data or a one-line user error, also
    where asammdf crashes its process."""
    pytest.importorskip("asammdf")
    from damper_emulator.dyno.column_map import ColumnMap
    from damper_emulator.dyno.mdf import read_mapped_mdf

    path = workdir / "data.mf4"
    path.write_bytes(blob)
    check_read(lambda: read_mapped_mdf(path, ColumnMap()))
