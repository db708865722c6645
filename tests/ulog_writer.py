"""A minimal PX4 ULog writer for tests: the file header, a flag-bits message, one format and one subscription
per topic, and data messages, byte for byte as the ULog specification lays them out (little endian)."""

from __future__ import annotations

import struct
from pathlib import Path

#: "ULog" followed by the format's magic bytes; then the version byte and the start timestamp (uint64, us).
MAGIC = b"ULog\x01\x12\x35"
LOCAL_POSITION_FIELDS = (("uint64_t", "timestamp"), ("float", "x"), ("float", "y"), ("float", "z"))
_PACK = {"uint64_t": "Q", "float": "f", "double": "d", "uint8_t": "B", "int32_t": "i"}


def _message(kind: str, payload: bytes) -> bytes:
    """One message: uint16 payload size, uint8 type, payload."""
    return struct.pack("<HB", len(payload), ord(kind)) + payload


def ulog_bytes(topics: dict[str, tuple[tuple[tuple[str, str], ...], list[tuple]]], start_us: int = 0) -> bytes:
    """A ULog file: topics maps a topic name to (fields as (type, name) pairs, rows of values in field order)."""
    out = bytearray(MAGIC + bytes([1]) + struct.pack("<Q", start_us))
    # Flag bits: 8 compatible and 8 incompatible flag bytes (all clear), 3 appended-data offsets (none).
    out += _message("B", bytes(16) + struct.pack("<3Q", 0, 0, 0))
    for name, (fields, _) in topics.items():
        out += _message("F", f"{name}:{''.join(f'{kind} {field};' for kind, field in fields)}".encode())
    for msg_id, (name, (fields, rows)) in enumerate(topics.items()):
        # Subscription: uint8 multi_id, uint16 msg_id, topic name.
        out += _message("A", struct.pack("<BH", 0, msg_id) + name.encode())
        layout = "<" + "".join(_PACK[kind] for kind, _ in fields)
        for row in rows:
            out += _message("D", struct.pack("<H", msg_id) + struct.pack(layout, *row))
    return bytes(out)


def write_local_position_ulog(path: Path, stamps_us: list[int], positions: list[tuple[float, float, float]],
                              start_us: int = 0) -> Path:
    """A ULog with vehicle_local_position samples (timestamp us; x, y, z m NED) at `path`; returns the path."""
    rows = [(stamp, *position) for stamp, position in zip(stamps_us, positions)]
    path.write_bytes(ulog_bytes({"vehicle_local_position": (LOCAL_POSITION_FIELDS, rows)}, start_us))
    return path
