"""A minimal reader of the protobuf wire format, for what the runtime reads of an ONNX file
without the `onnx` package (which it must not need): external-data locations
(`external_data.py`) and the custom nodes' recorded shapes (`static_check.py`); and the few
writers and `rewrite_graph_fields`, with which `static_check.fill_optional_attributes` adds an
attribute to a node and `layout.with_layout` rewrites an initializer."""

from __future__ import annotations

from collections.abc import Callable, Iterator


class Malformed(ValueError):
    """The bytes are not a well-formed protobuf message."""


def varint(buf: memoryview, i: int) -> tuple[int, int]:
    """(the varint at `i`, the index after it)."""
    value, shift = 0, 0
    while True:
        if i >= len(buf) or shift > 63:
            raise Malformed("truncated varint")
        b = buf[i]
        i += 1
        value |= (b & 0x7F) << shift
        if b < 0x80:
            return value, i
        shift += 7


def fields(buf: memoryview) -> Iterator[tuple[int, int | memoryview | None]]:
    """(field number, value) of one message: an int for a varint, the payload of a
    length-delimited field, None for a fixed 32- or 64-bit one (skipped)."""
    i = 0
    while i < len(buf):
        key, i = varint(buf, i)
        number, wire = key >> 3, key & 7
        if wire == 0:
            value, i = varint(buf, i)
            yield number, value
        elif wire in (1, 5):
            i += 8 if wire == 1 else 4
            yield number, None
        elif wire == 2:
            size, i = varint(buf, i)
            if i + size > len(buf):
                raise Malformed("field runs past the end")
            yield number, buf[i : i + size]
            i += size
        else:
            raise Malformed(f"unsupported wire type {wire}")
    if i != len(buf):
        raise Malformed("truncated field")


def payloads(buf: memoryview) -> Iterator[tuple[int, memoryview]]:
    """(field number, payload) of the length-delimited fields of one message."""
    for number, value in fields(buf):
        if isinstance(value, memoryview):
            yield number, value


def spans(buf: memoryview) -> Iterator[tuple[int, int, int, int | memoryview | None]]:
    """(field number, start, end, value) of one message's fields: `fields` with each field's
    byte span [start, end) in `buf` (its key included), to copy the fields left unchanged."""
    i = 0
    for number, value in fields(buf):
        start = i
        _, i = varint(buf, i)  # the key
        if isinstance(value, memoryview):
            size, i = varint(buf, i)
            i += size
        elif value is None:
            i += 8 if (buf[start] & 7) == 1 else 4
        else:
            _, i = varint(buf, i)
        yield number, start, i, value


def encode_varint(value: int) -> bytes:
    """The varint of a non-negative int below 2^64 (a negative int64: add 2^64 first)."""
    out = bytearray()
    while True:
        b = value & 0x7F
        value >>= 7
        if value:
            out.append(b | 0x80)
        else:
            out.append(b)
            return bytes(out)


def length_delimited(number: int, payload: bytes) -> bytes:
    """Field `number` holding `payload` (a string, bytes or a nested message)."""
    return encode_varint(number << 3 | 2) + encode_varint(len(payload)) + payload


def varint_field(number: int, value: int) -> bytes:
    """Field `number` holding the int `value` (int64 two's complement when negative)."""
    return encode_varint(number << 3) + encode_varint(value % (1 << 64))


MODEL_GRAPH = 7  # ModelProto.graph


def rewrite_graph_fields(
    data: bytes, number: int, rewrite: Callable[[memoryview], bytes | None]
) -> bytes | None:
    """The model `data` with each field `number` of its main graph (e.g. 1 a node, 5 an
    initializer) replaced by `rewrite(payload)` where that is not None, every other byte kept;
    None when nothing was replaced. Raises Malformed for bytes that are not a message."""
    buf = memoryview(data)
    out, changed = bytearray(), False
    for n, start, end, value in spans(buf):
        if n == MODEL_GRAPH and isinstance(value, memoryview):
            graph = bytearray()
            for gn, gstart, gend, gvalue in spans(value):
                new = rewrite(gvalue) if gn == number and isinstance(gvalue, memoryview) else None
                graph += value[gstart:gend] if new is None else length_delimited(gn, new)
                changed |= new is not None
            out += length_delimited(n, bytes(graph))
        else:
            out += buf[start:end]
    return bytes(out) if changed else None
