#!/usr/bin/env python3
"""The package's binary container (model files, checkpoints; common/container.h)
read from Python: an 8-byte magic, u32 version, u32 section count (0 in
version-1 model files: two sections), a u64 length per section, the sections,
and a u64 FNV-1a checksum of everything before it.
   scripts/container.py check FILE     exit 0 when FILE is whole (lengths and checksum agree)"""
import struct
import sys


def _layout(data):
    count = struct.unpack_from("<I", data, 12)[0] or 2
    lengths = struct.unpack_from("<%dQ" % count, data, 16)
    return 16 + 8 * count, lengths


def sections(data):
    """The sections of a container's bytes (no checks beyond the lengths)."""
    at, lengths = _layout(data)
    out = []
    for n in lengths:
        out.append(data[at:at + n])
        at += n
    return out


def is_whole(data):
    try:
        at, lengths = _layout(data)
    except struct.error:
        return False
    body = at + sum(lengths)
    h = 0xcbf29ce484222325
    for b in data[:body]:
        h = ((h ^ b) * 0x100000001b3) & 0xFFFFFFFFFFFFFFFF
    return len(data) == body + 8 and struct.unpack_from("<Q", data, body)[0] == h


if __name__ == "__main__":
    if len(sys.argv) != 3 or sys.argv[1] != "check":
        sys.exit(__doc__)
    sys.exit(0 if is_whole(open(sys.argv[2], "rb").read()) else 1)
