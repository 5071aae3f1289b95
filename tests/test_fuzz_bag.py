"""Property-based tests of the bag reader (``damper_emulator.bag``).

A bag comes from a recorder that may have been killed, a disk that filled up, a copy cut
short or another tool: :func:`open_bag` must open it or raise :class:`BagError`, and
reading every message (:meth:`Bag.messages`, :func:`read_messages`) must give messages or
:class:`BagError` (the one-line user error the command line prints, exit 2), whatever the
directory holds: never another exception, never a hang.  An error names the bag.

The bags: a small closed bag written by the project's own :class:`BagWriter` (three
topics of the three message types the project records, several chunks), its MCAP file
truncated, with bytes flipped, overwritten, inserted or deleted; its ``metadata.yaml``
with a value replaced by a random YAML scalar, replaced by random YAML or bytes, or cut;
files deleted or replaced by a directory; and bags whose messages are random bytes (the
CDR decoder, :func:`messages.deserialize`, which is also fed random bytes directly).
"""

from __future__ import annotations

import re
import shutil

import numpy as np
import pytest
import yaml
from fuzz_support import junk_bytes, junk_text, mutated_bytes, time_limit
from hypothesis import given
from hypothesis import strategies as st

from damper_emulator.bag import BagError, BagWriter, cdr_fast, messages, open_bag, read_messages

JS, F64, DIAG = messages.JOINT_STATE, messages.FLOAT64, messages.DIAGNOSTIC_ARRAY
T0 = 1_700_000_000_000_000_000


def _write_bag(path, payloads: list[tuple[str, bytes]] | None = None) -> None:
    """A closed bag at ``path``: three topics, 24 messages in three flushes (chunks);
    with ``payloads``, those ``(msgtype, data)`` as the messages instead."""
    with BagWriter(path, flush_period_s=3600, fsync=False) as w:
        topics = {JS: w.add_topic("/damper/state", JS), F64: w.add_topic("/cmd", F64),
                  DIAG: w.add_topic("/diagnostics", DIAG)}
        if payloads is not None:
            for i, (msgtype, data) in enumerate(payloads):
                w.write(topics[msgtype], T0 + i * 1000, data)
            return
        for i in range(24):
            t = T0 + i * 1_000_000
            w.write(topics[JS], t, messages.joint_state(t, ["damper"], [i * 1e-3], [0.1],
                                                        [i * 10.0]))
            if i % 4 == 0:
                w.write(topics[F64], t + 1, messages.float64(i / 24))
            if i % 8 == 0:
                w.write(topics[DIAG], t + 2, messages.diagnostic_array(
                    t, [(0, "emulator", "ok", "hil", [("period_ms", "1.0")])]))
            if i % 8 == 7:
                w.flush()


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """``(mcap bytes, metadata.yaml bytes, mcap file name)`` of the small closed bag, and
    a work directory for the corrupted copies."""
    root = tmp_path_factory.mktemp("fuzz_bag")
    _write_bag(root / "base")
    (mcap,) = (root / "base").glob("*.mcap")
    with open_bag(root / "base") as bag:  # the starting point reads (else this tests nothing)
        assert len(list(bag.messages())) == bag.message_count == 24 + 6 + 3
    return mcap.read_bytes(), (root / "base" / "metadata.yaml").read_bytes(), mcap.name, root


#: ``key: value`` of one line of a YAML file (the value to replace)
_VALUE = re.compile(rb"^(\s*(?:- )?[^#\s][^:#\n]*:[ ]+)([^#\n]+?)(\s*(?:#.*)?)$", re.M)

#: YAML scalars as text: numbers of every size, negative counts, wrong types, tags
scalar_texts = st.one_of(
    st.sampled_from(("0", "-1", "1" + "0" * 30, "1" + "0" * 5000, ".nan", "-.inf", "~", "''",
                     "[]", "{}", "[1, 2]", "{a: 1}", "true", "x", "mcap", "sqlite3", "cdr",
                     "zstd", "message", "file", "'../../etc/passwd'", "/", "2001-02-30",
                     "!!binary x", "*nowhere", "&a 1", "[", "'", "RIHS01_", "\"\\x00\"")),
    st.integers().map(str),
    st.floats().map(repr),
    st.text(st.characters(codec="utf-8", exclude_categories=("Cs", "Cc")), max_size=12),
)

#: random YAML documents
documents = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=10),
    lambda inner: st.lists(inner, max_size=4)
    | st.dictionaries(st.text(max_size=10), inner, max_size=4),
    max_leaves=16,
)


@st.composite
def metadata_files(draw: st.DrawFn, original: bytes) -> bytes:
    """``metadata.yaml`` changed: a value replaced, or all of it random YAML or bytes,
    or its bytes changed."""
    kind = draw(st.sampled_from(("value", "value", "value", "yaml", "bytes", "mutated")))
    spans = [m.span(2) for m in _VALUE.finditer(original)]
    if kind == "value" and spans:
        out = original
        for _ in range(draw(st.integers(1, 3))):
            start, end = draw(st.sampled_from(spans))
            out = out[:start] + draw(scalar_texts).encode() + out[end:]
            spans = [m.span(2) for m in _VALUE.finditer(out)] or spans
        return out
    if kind == "yaml":
        doc = draw(documents)
        if draw(st.booleans()):
            doc = {"rosbag2_bagfile_information": doc}
        return yaml.safe_dump(doc).encode()
    if kind == "bytes":
        return draw(junk_bytes | junk_text.map(lambda s: s.encode()))
    return draw(mutated_bytes(original))


@st.composite
def corrupted_bags(draw: st.DrawFn, mcap: bytes, metadata: bytes,
                   mcap_name: str) -> dict[str, bytes | None]:
    """The files of a corrupted copy of the base bag, by name (None: a directory in its
    place); a name left out is a file deleted."""
    files: dict[str, bytes | None] = {mcap_name: mcap, "metadata.yaml": metadata}
    for _ in range(draw(st.integers(1, 2))):
        what = draw(st.sampled_from(("mcap", "mcap", "mcap", "metadata", "metadata", "files")))
        if what == "mcap" and files.get(mcap_name):
            files[mcap_name] = draw(mutated_bytes(files[mcap_name] or b""))
        elif what == "metadata" and files.get("metadata.yaml"):
            files["metadata.yaml"] = draw(metadata_files(files["metadata.yaml"] or b""))
        else:
            name = draw(st.sampled_from((mcap_name, "metadata.yaml")))
            op = draw(st.sampled_from(("delete", "directory", "empty")))
            if op == "delete":
                files.pop(name, None)
            else:
                files[name] = None if op == "directory" else b""
    return files


def _materialize(path, files: dict[str, bytes | None]) -> None:
    shutil.rmtree(path, ignore_errors=True)
    path.mkdir()
    for name, data in files.items():
        if data is None:
            (path / name).mkdir()
        else:
            (path / name).write_bytes(data)


def check_bag(path) -> None:
    """Open the bag and read every message, twice (:func:`open_bag` and
    :func:`read_messages`): messages of the bag's topics, or a :class:`BagError` naming
    the bag; :meth:`Bag.raw_messages` too."""
    try:
        with time_limit(), open_bag(path) as bag:
            topics = dict(bag.topics)
            assert bag.message_count == sum(t.count for t in topics.values())
            raw = list(bag.raw_messages())
            got = list(bag.messages())
    except BagError as exc:
        assert str(path) in str(exc)
    else:
        assert len(got) == len(raw)
        for topic, stamp, _ in got:
            assert topic in topics and isinstance(stamp, int)
    try:
        with time_limit():
            again = list(read_messages(path))
    except BagError as exc:
        assert str(path) in str(exc)
    else:
        assert all(topic in topics for topic, _, _ in again)


@given(data=st.data())
def test_bag_corrupted(base, data):
    """A corrupted copy of a good bag: messages or BagError."""
    mcap, metadata, mcap_name, root = base
    files = data.draw(corrupted_bags(mcap, metadata, mcap_name), label="files")
    path = root / "corrupted"
    _materialize(path, files)
    check_bag(path)


payloads = st.lists(st.tuples(st.sampled_from((JS, F64, DIAG)), st.binary(max_size=200)),
                    min_size=1, max_size=8)


@given(payloads=payloads)
def test_bag_random_payloads(base, payloads):
    """A well-formed bag whose messages are random bytes: messages or BagError."""
    path = base[3] / "payloads"
    shutil.rmtree(path, ignore_errors=True)
    _write_bag(path, payloads)
    check_bag(path)


@given(msgtype=st.sampled_from((JS, F64, DIAG)), data=st.binary(max_size=300))
def test_deserialize_random_bytes(msgtype, data):
    """The CDR decoder on random bytes: a message or BagError."""
    try:
        with time_limit():
            msg = messages.deserialize(data, msgtype)
    except BagError as exc:
        assert msgtype in str(exc)
    else:
        assert isinstance(msg, messages.typestore().types[msgtype])


_KEPT = cdr_fast.encode_joint_state(1_700_000_000_000_000_001, ["damper", "damper/status"],
                                    [0.01, 2e-4], [0.2, 0.0], [812.5, 0.0])


@given(data=st.one_of(st.binary(max_size=300), mutated_bytes(_KEPT)))
def test_the_live_nodes_joint_state_decoder_on_any_bytes(data):
    """What a node's raw subscription may hand it (ros.common.JointStateIn): the decoder
    with a layout kept from a good message, on random or damaged bytes, gives a sample
    whose fields are what the general parser reads, or BagError."""
    decoder = cdr_fast.JointStateDecoder()
    decoder.decode(_KEPT)
    try:
        with time_limit():
            got = decoder.decode(data)
    except BagError as exc:
        assert "cannot decode" in str(exc)
        return
    stamp, frame, names, p, v, e = cdr_fast.decode_joint_state(data)
    assert (got.stamp_ns, got.frame_id, got.name) == (stamp, frame, names)
    for a, b in ((got.position, p), (got.velocity, v), (got.effort, e)):
        assert np.array_equal(np.array(a, dtype=float), b, equal_nan=True)
