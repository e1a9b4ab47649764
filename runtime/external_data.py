"""Where an ONNX model's external data may live: inside the model's folder, nowhere else.

A large model keeps tensors in side files named by `external_data` entries (`location`) of
its TensorProtos. ONNX Runtime only refuses locations outside the model's folder in its newer
versions, and this project supports onnxruntime >= 1.20; a model file from elsewhere could
otherwise make the runtime read any file the process can (`../../secret`, `/etc/...`, or a
symlink out of the folder). `check_external_data` finds every location without the `onnx`
package (which the runtime must not need): a small reader of the protobuf wire format walks
only the messages that can hold tensors (graphs, nodes, attributes, functions, training info)
and skips every other field by its length. A file without the bytes `location` has no
external data and is not parsed at all.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

from .errors import InputError
from .protobuf import Malformed, payloads

# Field numbers (onnx/onnx.proto3) of the messages that can contain TensorProtos.
_MODEL = {7: "graph", 20: "training_info", 25: "function"}
_TRAINING_INFO = {1: "graph", 2: "graph"}
_FUNCTION = {7: "node"}
_GRAPH = {1: "node", 5: "tensor", 15: "sparse"}
_NODE = {5: "attribute"}
_ATTRIBUTE = {5: "tensor", 6: "graph", 10: "tensor", 11: "graph", 22: "sparse", 23: "sparse"}
_SPARSE = {1: "tensor", 2: "tensor"}
_TENSOR_EXTERNAL_DATA = 13
_ENTRY_KEY, _ENTRY_VALUE = 1, 2


_KINDS = {
    "model": _MODEL,
    "training_info": _TRAINING_INFO,
    "function": _FUNCTION,
    "graph": _GRAPH,
    "node": _NODE,
    "attribute": _ATTRIBUTE,
    "sparse": _SPARSE,
}


def _locations(buf: memoryview, kind: str, depth: int = 0) -> Iterator[str]:
    if depth > 64:
        raise Malformed("graphs nested too deep")
    if kind == "tensor":
        for number, payload in payloads(buf):
            if number == _TENSOR_EXTERNAL_DATA:
                entry = {n: bytes(p) for n, p in payloads(payload)}
                if entry.get(_ENTRY_KEY) == b"location":
                    yield entry.get(_ENTRY_VALUE, b"").decode("utf-8", "replace")
        return
    children = _KINDS[kind]
    for number, payload in payloads(buf):
        child = children.get(number)
        if child is not None:
            yield from _locations(payload, child, depth + 1)


def external_locations(data: bytes) -> list[str]:
    """Every external-data `location` in a serialized ModelProto, in file order.

    ValueError if the bytes are not a well-formed protobuf message.
    """
    if b"location" not in data:  # the key of every external_data entry
        return []
    try:
        return list(_locations(memoryview(data), "model"))
    except Malformed as exc:
        raise ValueError(f"not a well-formed ONNX protobuf ({exc})") from None


def check_external_data(model: str | os.PathLike | bytes, data: bytes | None = None) -> list[Path]:
    """The external data files of `model` (a path, or serialized bytes), after checking that
    each exists and, symlinks resolved, lies inside both the folder of the path as given (where
    ONNX Runtime reads it) and the folder of the model file itself (what newer versions allow).
    InputError naming the model and the location otherwise; a model given as bytes may have
    no external data. data: the file's bytes when the caller has read them already."""
    if isinstance(model, (bytes, bytearray)):
        source, data, folder = "<model bytes>", bytes(model), None
    else:
        path = Path(model)
        # ONNX Runtime joins each location to the folder of the path it was given, without
        # following the model file's own link: with B/m.onnx -> A/m.onnx it reads B/<location>
        # (1.20 then reads whatever that is; 1.32 also wants it inside A). So the data is
        # looked up beside the given path and must resolve into both folders: the same
        # models load on every version.
        source, folder = str(path), path.parent.resolve()
        data = path.read_bytes() if data is None else data
        target_folder = path.resolve().parent
    try:
        locations = external_locations(data)
    except ValueError as exc:
        raise InputError(f"{source}: {exc}") from None
    files = []
    for location in locations:
        if folder is None:
            raise InputError(
                f"{source}: the model keeps tensor data in {location!r}; give its path, not "
                "its bytes, so that the data file can be found beside it"
            )
        if not location or "\0" in location:
            raise InputError(f"{source}: bad external data location {location!r}")
        if os.path.isabs(location) or Path(location).anchor:
            raise InputError(
                f"{source}: external data location {location!r} is an absolute path; it must "
                "be a file inside the model's folder"
            )
        target = (folder / location).resolve()
        if not target.is_relative_to(folder):
            raise InputError(
                f"{source}: external data location {location!r} points outside the model's "
                f"folder {folder} (to {target}); refused"
            )
        if not target.is_file():
            raise InputError(f"{source}: external data file {location!r} not found in {folder}")
        if not target.is_relative_to(target_folder):
            raise InputError(
                f"{source}: external data location {location!r} points outside the model's "
                f"folder {target_folder} (the model file links there; the data resolves to "
                f"{target}); refused: keep the model and its data in one folder"
            )
        files.append(target)
    return files


__all__ = ["check_external_data", "external_locations"]
