"""Byte encoding of the MCAP records the bag writer needs.

Every function returns one complete record: opcode (u8), body length (u64,
little endian) and body, laid out as in the MCAP specification
(https://mcap.dev/spec). Strings are u32-length-prefixed UTF-8, maps are a
u32 byte length followed by key/value pairs, arrays a u32 byte length
followed by their entries.

``PAD`` is a private record (opcodes 0x80..0xFF are reserved for private
records and readers skip records they do not know by their length). The
writer uses it to cover the not yet used, reserved part of the file and as a
9-byte filler.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable, Mapping, Sequence

MAGIC = b"\x89MCAP0\r\n"

OP_HEADER = 0x01
OP_FOOTER = 0x02
OP_SCHEMA = 0x03
OP_CHANNEL = 0x04
OP_MESSAGE = 0x05
OP_CHUNK = 0x06
OP_MESSAGE_INDEX = 0x07
OP_CHUNK_INDEX = 0x08
OP_STATISTICS = 0x0B
OP_METADATA = 0x0C
OP_METADATA_INDEX = 0x0D
OP_SUMMARY_OFFSET = 0x0E
OP_DATA_END = 0x0F
OP_PAD = 0x80  # private: reserved space / filler

RECORD_HEADER_SIZE = 9  # opcode + u64 length
DATA_END_SIZE = RECORD_HEADER_SIZE + 4
FOOTER_SIZE = RECORD_HEADER_SIZE + 20
#: Message record prefix: opcode, length, channel id, sequence, log time, publish time.
MESSAGE_PREFIX = struct.Struct("<BQHIQQ")

_U16 = struct.Struct("<H")
_U32 = struct.Struct("<I")
_U64 = struct.Struct("<Q")
_RECORD_HEADER = struct.Struct("<BQ")


def record(opcode: int, body: bytes) -> bytes:
    """Frame ``body`` as one record with ``opcode``."""
    return _RECORD_HEADER.pack(opcode, len(body)) + body


def record_header(opcode: int, length: int) -> bytes:
    """The 9 bytes opening a record of ``length`` body bytes."""
    return _RECORD_HEADER.pack(opcode, length)


def string(value: str) -> bytes:
    """MCAP string: u32 byte length and UTF-8 bytes."""
    data = value.encode()
    return _U32.pack(len(data)) + data


def string_map(entries: Mapping[str, str]) -> bytes:
    """MCAP ``Map<string, string>``."""
    body = b"".join(string(k) + string(v) for k, v in entries.items())
    return _U32.pack(len(body)) + body


def header(profile: str, library: str) -> bytes:
    """Header record."""
    return record(OP_HEADER, string(profile) + string(library))


def footer(summary_start: int, summary_offset_start: int, summary_crc: int) -> bytes:
    """Footer record (always 29 bytes)."""
    return record(OP_FOOTER, struct.pack("<QQI", summary_start, summary_offset_start, summary_crc))


def data_end(data_section_crc: int = 0) -> bytes:
    """DataEnd record (always 13 bytes)."""
    return record(OP_DATA_END, _U32.pack(data_section_crc))


def pad(length: int) -> bytes:
    """Header of a PAD record whose ``length`` content bytes follow in the file."""
    return _RECORD_HEADER.pack(OP_PAD, length)


def schema(schema_id: int, name: str, encoding: str, data: bytes) -> bytes:
    """Schema record."""
    return record(
        OP_SCHEMA,
        _U16.pack(schema_id) + string(name) + string(encoding) + _U32.pack(len(data)) + data,
    )


def channel(
    channel_id: int,
    schema_id: int,
    topic: str,
    message_encoding: str,
    metadata: Mapping[str, str],
) -> bytes:
    """Channel record."""
    return record(
        OP_CHANNEL,
        _U16.pack(channel_id)
        + _U16.pack(schema_id)
        + string(topic)
        + string(message_encoding)
        + string_map(metadata),
    )


def chunk(start_time: int, end_time: int, records: bytes, crc: int) -> bytes:
    """Uncompressed Chunk record holding ``records``."""
    return record(
        OP_CHUNK,
        struct.pack("<QQQI", start_time, end_time, len(records), crc)
        + string("")
        + _U64.pack(len(records))
        + records,
    )


def chunk_prefix_size() -> int:
    """Bytes from the start of a Chunk record to its first inner record."""
    return RECORD_HEADER_SIZE + 8 + 8 + 8 + 4 + 4 + 8


def message_index(channel_id: int, entries: Sequence[tuple[int, int]]) -> bytes:
    """MessageIndex record: ``(log_time, offset in the chunk's records)`` pairs."""
    flat = [v for pair in entries for v in pair]
    body = (
        _U16.pack(channel_id) + _U32.pack(16 * len(entries)) + struct.pack(f"<{len(flat)}Q", *flat)
    )
    return record(OP_MESSAGE_INDEX, body)


def chunk_index(
    start_time: int,
    end_time: int,
    chunk_start: int,
    chunk_length: int,
    index_offsets: Iterable[tuple[int, int]],
    index_length: int,
    records_size: int,
) -> bytes:
    """ChunkIndex record for an uncompressed chunk."""
    offsets = b"".join(_U16.pack(cid) + _U64.pack(off) for cid, off in index_offsets)
    body = (
        struct.pack("<QQQQ", start_time, end_time, chunk_start, chunk_length)
        + _U32.pack(len(offsets))
        + offsets
        + _U64.pack(index_length)
        + string("")
        + _U64.pack(records_size)
        + _U64.pack(records_size)
    )
    return record(OP_CHUNK_INDEX, body)


def metadata(name: str, entries: Mapping[str, str]) -> bytes:
    """Metadata record."""
    return record(OP_METADATA, string(name) + string_map(entries))


def metadata_index(offset: int, length: int, name: str) -> bytes:
    """MetadataIndex record."""
    return record(OP_METADATA_INDEX, _U64.pack(offset) + _U64.pack(length) + string(name))


def statistics(
    message_count: int,
    schema_count: int,
    channel_count: int,
    metadata_count: int,
    chunk_count: int,
    start_time: int,
    end_time: int,
    channel_counts: Mapping[int, int],
) -> bytes:
    """Statistics record."""
    counts = b"".join(_U16.pack(cid) + _U64.pack(n) for cid, n in sorted(channel_counts.items()))
    body = (
        struct.pack(
            "<QHIIIIQQ",
            message_count,
            schema_count,
            channel_count,
            0,  # attachments
            metadata_count,
            chunk_count,
            start_time,
            end_time,
        )
        + _U32.pack(len(counts))
        + counts
    )
    return record(OP_STATISTICS, body)


def summary_offset(group_opcode: int, group_start: int, group_length: int) -> bytes:
    """SummaryOffset record."""
    return record(OP_SUMMARY_OFFSET, struct.pack("<BQQ", group_opcode, group_start, group_length))
