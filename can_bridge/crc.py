"""CRC-8/SAE-J1850, the checksum of every frame in ``config/damper.dbc``.

Parameters (the catalogue's "CRC-8/SAE-J1850"): width 8, polynomial 0x1D, initial value
0xFF, no input or output reflection, final XOR 0xFF; check value 0x4B for the ASCII bytes
``b"123456789"``.
"""

from __future__ import annotations

__all__ = ["CRC8_SAE_J1850_CHECK", "crc8_sae_j1850"]

_POLY = 0x1D
_INIT = 0xFF
_XOROUT = 0xFF

#: The catalogue check value: ``crc8_sae_j1850(b"123456789")``.
CRC8_SAE_J1850_CHECK = 0x4B


def _make_table(poly: int) -> bytes:
    table = bytearray(256)
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ poly) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table[byte] = crc
    return bytes(table)


_TABLE = _make_table(_POLY)


def crc8_sae_j1850(data: bytes | bytearray | memoryview) -> int:
    """CRC-8/SAE-J1850 of ``data``.

    Parameters
    ----------
    data : bytes-like
        The bytes, in transmission order.

    Returns
    -------
    int
        The CRC, 0..255.

    Examples
    --------
    >>> hex(crc8_sae_j1850(b"123456789"))
    '0x4b'
    """
    crc = _INIT
    table = _TABLE
    for byte in data:
        crc = table[crc ^ byte]
    return crc ^ _XOROUT
