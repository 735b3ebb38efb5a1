"""The serialized FMU state: a versioned, checksummed, size-bounded binary format.

Nothing in it is executable: the payload is a restricted tree (dict with str keys, list,
str, int, float, bool, None, and numpy arrays of a few plain dtypes) written as tagged
fields, and the reader only parses bytes. Layout (integers little-endian):

====== ======= =====================================================================
offset size    field
====== ======= =====================================================================
0      8       magic ``b"MBDFMUST"``
8      2       format version (``VERSION``)
10     2       reserved, 0
12     8       payload length n (at most ``MAX_PAYLOAD`` bytes)
20     32      SHA-256 of the FMU's GUID: the state loads only into the FMU that wrote it
52     n       payload: one tagged value (below)
52+n   32      SHA-256 of every byte before it
====== ======= =====================================================================

Tags: ``N`` None, ``T``/``F`` bool, ``i`` int64, ``d`` float64, ``s`` str (u32 length +
UTF-8), ``l`` list (u32 count + values), ``m`` dict (u32 count + (u32 length + UTF-8 key,
value) pairs), ``a`` array (u8 dtype code, u8 ndim, u32 per dimension, raw C-order data).

The checksum catches damage (truncation, flipped bytes); it is not a signature. A blob
made on purpose with a valid checksum still goes through the same strict parser and then
through the slave's own checks of the tree, so at worst it is refused or restores
values of the right types.
"""

from __future__ import annotations

import hashlib
import struct

import numpy as np

MAGIC = b"MBDFMUST"
VERSION = 1
HEADER = struct.Struct("<8sHHQ32s")
DIGEST_SIZE = 32
MAX_PAYLOAD = 64 * 2**20    # bytes: a state larger than this is refused both ways
MAX_DEPTH = 32              # nesting of lists and dicts
MAX_NDIM = 8                # array dimensions
# dtype code <-> numpy dtype (little-endian, fixed size: no objects, no strings)
DTYPES = {1: np.dtype("<f8"), 2: np.dtype("<f4"), 3: np.dtype("<i8"), 4: np.dtype("<i4"),
          5: np.dtype("|u1"), 6: np.dtype("|b1")}
_CODES = {dtype: code for code, dtype in DTYPES.items()}
_U32 = struct.Struct("<I")
_I64 = struct.Struct("<q")
_F64 = struct.Struct("<d")


class StateFormatError(ValueError):
    """A state that cannot be written or read (the message says why)."""


def fmu_digest(guid: str) -> bytes:
    """The 32 bytes that tie a serialized state to one FMU."""
    return hashlib.sha256(guid.encode("utf-8")).digest()


def dumps(tree, guid: str) -> bytes:
    """Serialize ``tree`` for the FMU with ``guid``; StateFormatError if it has other types."""
    parts: list[bytes] = []
    _encode(tree, parts, 0)
    payload = b"".join(parts)
    if len(payload) > MAX_PAYLOAD:
        raise StateFormatError(f"the state is {len(payload)} bytes, more than {MAX_PAYLOAD}")
    head = HEADER.pack(MAGIC, VERSION, 0, len(payload), fmu_digest(guid))
    return head + payload + hashlib.sha256(head + payload).digest()


def loads(blob: bytes, guid: str):
    """The tree in ``blob``; StateFormatError naming the first problem found."""
    blob = bytes(blob)
    if len(blob) < HEADER.size + DIGEST_SIZE:
        raise StateFormatError(f"{len(blob)} bytes is too short for a state")
    magic, version, _, size, digest = HEADER.unpack_from(blob)
    if magic != MAGIC:
        raise StateFormatError("not an mbdfmu FMU state (wrong magic bytes)")
    if version != VERSION:
        raise StateFormatError(f"state format version {version}; this FMU reads {VERSION}")
    if size > MAX_PAYLOAD or len(blob) != HEADER.size + size + DIGEST_SIZE:
        raise StateFormatError(f"the length ({len(blob)} bytes) does not match the header "
                               f"(payload {size} bytes): truncated or padded")
    body = blob[:HEADER.size + size]
    if hashlib.sha256(body).digest() != blob[-DIGEST_SIZE:]:
        raise StateFormatError("checksum mismatch: the state was damaged")
    if digest != fmu_digest(guid):
        raise StateFormatError("the state was written by another FMU (GUID differs)")
    tree, end = _decode(body, HEADER.size, 0)
    if end != len(body):
        raise StateFormatError(f"{len(body) - end} stray bytes after the state")
    return tree


def _encode(value, parts: list, depth: int) -> None:
    """Append the tagged form of ``value`` to ``parts``."""
    if depth > MAX_DEPTH:
        raise StateFormatError(f"the state is nested deeper than {MAX_DEPTH}")
    if value is None or isinstance(value, (bool, np.bool_)):
        parts.append(b"N" if value is None else b"T" if value else b"F")
    elif isinstance(value, (int, np.integer)):
        if not -2**63 <= int(value) < 2**63:
            raise StateFormatError(f"integer {value} does not fit in 64 bits")
        parts.append(b"i" + _I64.pack(int(value)))
    elif isinstance(value, (float, np.floating)):
        parts.append(b"d" + _F64.pack(float(value)))
    elif isinstance(value, str):
        _encode_text(value, b"s", parts)
    elif isinstance(value, (list, tuple)):
        parts.append(b"l" + _U32.pack(len(value)))
        for item in value:
            _encode(item, parts, depth + 1)
    elif isinstance(value, dict):
        parts.append(b"m" + _U32.pack(len(value)))
        for key, item in value.items():
            if not isinstance(key, str):
                raise StateFormatError(f"dict key {key!r} is not a str")
            _encode_text(key, b"", parts)
            _encode(item, parts, depth + 1)
    elif isinstance(value, np.ndarray):
        _encode_array(value, parts)
    else:
        raise StateFormatError(f"a state cannot hold {type(value).__name__} values")


def _encode_text(text: str, tag: bytes, parts: list) -> None:
    data = text.encode("utf-8")
    parts.append(tag + _U32.pack(len(data)) + data)


def _encode_array(array: np.ndarray, parts: list) -> None:
    dtype = array.dtype.newbyteorder("<") if array.dtype.byteorder == ">" else array.dtype
    code = _CODES.get(np.dtype(dtype))
    if code is None or array.ndim > MAX_NDIM:
        raise StateFormatError(f"arrays of dtype {array.dtype} with {array.ndim} dimensions "
                               "cannot be stored")
    data = np.ascontiguousarray(array, dtype=DTYPES[code]).tobytes()
    parts.append(b"a" + bytes((code, array.ndim)) + b"".join(_U32.pack(n) for n in array.shape)
                 + data)


def _take(blob: bytes, at: int, n: int) -> tuple[bytes, int]:
    """``n`` bytes of ``blob`` from ``at``, and the offset after them."""
    if n < 0 or at + n > len(blob):
        raise StateFormatError(f"truncated at byte {at}: {n} bytes needed, {len(blob) - at} left")
    return blob[at:at + n], at + n


def _decode(blob: bytes, at: int, depth: int):
    """The value starting at ``at``, and the offset after it."""
    if depth > MAX_DEPTH:
        raise StateFormatError(f"the state is nested deeper than {MAX_DEPTH}")
    tag, at = _take(blob, at, 1)
    if tag in (b"N", b"T", b"F"):
        return {b"N": None, b"T": True, b"F": False}[tag], at
    if tag == b"i":
        raw, at = _take(blob, at, 8)
        return _I64.unpack(raw)[0], at
    if tag == b"d":
        raw, at = _take(blob, at, 8)
        return _F64.unpack(raw)[0], at
    if tag == b"s":
        return _decode_text(blob, at)
    if tag in (b"l", b"m"):
        return _decode_container(blob, at, depth, tag == b"m")
    if tag == b"a":
        return _decode_array(blob, at)
    raise StateFormatError(f"unknown tag {tag!r} at byte {at - 1}")


def _decode_text(blob: bytes, at: int) -> tuple[str, int]:
    raw, at = _take(blob, at, 4)
    data, at = _take(blob, at, _U32.unpack(raw)[0])
    try:
        return data.decode("utf-8"), at
    except UnicodeDecodeError as exc:
        raise StateFormatError(f"text before byte {at} is not UTF-8 ({exc.reason})") from None


def _decode_container(blob: bytes, at: int, depth: int, is_dict: bool):
    raw, at = _take(blob, at, 4)
    count = _U32.unpack(raw)[0]
    if count > len(blob) - at:     # every item takes at least one byte
        raise StateFormatError(f"a container at byte {at - 5} claims {count} items")
    if not is_dict:
        items = []
        for _ in range(count):
            item, at = _decode(blob, at, depth + 1)
            items.append(item)
        return items, at
    result = {}
    for _ in range(count):
        key, at = _decode_text(blob, at)
        if key in result:
            raise StateFormatError(f"duplicate key {key!r} before byte {at}")
        result[key], at = _decode(blob, at, depth + 1)
    return result, at


def _decode_array(blob: bytes, at: int) -> tuple[np.ndarray, int]:
    raw, at = _take(blob, at, 2)
    code, ndim = raw[0], raw[1]
    if code not in DTYPES or ndim > MAX_NDIM:
        raise StateFormatError(f"array with dtype code {code} and {ndim} dimensions at byte {at - 3}")
    raw, at = _take(blob, at, 4 * ndim)
    shape = struct.unpack(f"<{ndim}I", raw)
    count = 1
    for n in shape:
        count *= n
    data, at = _take(blob, at, count * DTYPES[code].itemsize)
    array = np.frombuffer(data, dtype=DTYPES[code]).reshape(shape).copy()
    if code == 6 and data.translate(None, b"\x00\x01"):
        raise StateFormatError(f"boolean array before byte {at} holds bytes other than 0 and 1")
    return array, at
