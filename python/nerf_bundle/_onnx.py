"""What the package checks in a graph file before onnxruntime sees it (``bundle/src/graph.rs``):
no tensor whose data lies in another file (onnxruntime would read that file, named by the
graph, from wherever the path leads), and initializers of the types the graphs use. A minimal
protobuf reader of the ONNX messages, so the package needs no ``onnx``."""
from __future__ import annotations

from typing import Iterator, Set, Tuple

from ._validate import BundleError

#: TensorProto.DataType values an initializer may have: float32, int32, int64, float16.
INITIALIZER_TYPES = {1: "float32", 6: "int32", 7: "int64", 10: "float16"}
#: TensorProto.DataLocation EXTERNAL.
EXTERNAL = 1
#: Subgraphs (If, Loop, Scan bodies) nested deeper than this are refused (prost stops at 100).
MAX_NESTING = 64

_Field = Tuple[int, int, int, int]  # (field number, wire type, value or start, end)


class _Malformed(Exception):
    pass


def _varint(buf: memoryview, at: int, end: int) -> Tuple[int, int]:
    value, shift = 0, 0
    while True:
        if at >= end or shift > 63:
            raise _Malformed("a varint runs past its message")
        b = buf[at]
        at += 1
        value |= (b & 0x7F) << shift
        if b < 0x80:
            return value, at
        shift += 7


def _fields(buf: memoryview, start: int, end: int) -> Iterator[_Field]:
    """The fields of the message in ``buf[start:end]``: (number, wire type, value, end of
    value); for length-delimited fields ``value`` is where the bytes start."""
    at = start
    while at < end:
        key, at = _varint(buf, at, end)
        number, wire = key >> 3, key & 7
        if number == 0:
            raise _Malformed("field number 0")
        if wire == 0:
            value, at = _varint(buf, at, end)
            yield number, wire, value, at
        elif wire == 1 or wire == 5:
            size = 8 if wire == 1 else 4
            if at + size > end:
                raise _Malformed("a fixed-size field runs past its message")
            at += size
            yield number, wire, 0, at
        elif wire == 2:
            length, at = _varint(buf, at, end)
            if at + length > end:
                raise _Malformed("a field runs past its message")
            yield number, wire, at, at + length
            at += length
        else:
            raise _Malformed(f"wire type {wire}")


def _text(buf: memoryview, start: int, end: int) -> str:
    return bytes(buf[start:end]).decode("utf-8", "replace")


class _Scan:
    def __init__(self, buf: memoryview) -> None:
        self.buf = buf

    def tensor(self, start: int, end: int, where: str, initializer: bool) -> None:
        """TensorProto: name 8, data_type 2, external_data 13, data_location 14."""
        name, dtype, external, location = "", 1, False, 0
        for number, wire, a, b in _fields(self.buf, start, end):
            if number == 8 and wire == 2:
                name = _text(self.buf, a, b)
            elif number == 2 and wire == 0:
                dtype = a
            elif number == 13 and wire == 2:
                external = True
            elif number == 14 and wire == 0:
                location = a
        label = f"{where} {name!r}" if name else where
        if external or location == EXTERNAL:
            raise BundleError(f"{label}: its data is stored outside the graph file (ONNX external data), "
                              "which bundles do not use: a bundle's graphs hold their weights")
        if initializer and dtype not in INITIALIZER_TYPES:
            raise BundleError(f"{label}: element type {dtype}; initializers must be one of "
                              f"{', '.join(f'{n} ({t})' for t, n in INITIALIZER_TYPES.items())}")

    def sparse(self, start: int, end: int, where: str, initializer: bool) -> None:
        """SparseTensorProto: values 1, indices 2."""
        for number, wire, a, b in _fields(self.buf, start, end):
            if number in (1, 2) and wire == 2:
                self.tensor(a, b, where, initializer)

    def attribute(self, start: int, end: int, depth: int) -> None:
        """AttributeProto: t 5, g 6, tensors 10, graphs 11, sparse_tensor 22, sparse_tensors 23."""
        for number, wire, a, b in _fields(self.buf, start, end):
            if wire != 2:
                continue
            if number in (5, 10):
                self.tensor(a, b, "attribute tensor", False)
            elif number in (22, 23):
                self.sparse(a, b, "attribute tensor", False)
            elif number in (6, 11):
                self.graph(a, b, depth + 1)

    def nodes_of(self, start: int, end: int, node_field: int, depth: int) -> None:
        """The attributes (field 5 of NodeProto) of the nodes in field ``node_field``."""
        for number, wire, a, b in _fields(self.buf, start, end):
            if number == node_field and wire == 2:
                for n2, w2, a2, b2 in _fields(self.buf, a, b):
                    if n2 == 5 and w2 == 2:
                        self.attribute(a2, b2, depth)

    def graph(self, start: int, end: int, depth: int) -> None:
        """GraphProto: node 1, initializer 5, sparse_initializer 15."""
        if depth > MAX_NESTING:
            raise _Malformed(f"subgraphs nested more than {MAX_NESTING} deep")
        for number, wire, a, b in _fields(self.buf, start, end):
            if wire != 2:
                continue
            if number == 5:
                self.tensor(a, b, "initializer", True)
            elif number == 15:
                self.sparse(a, b, "sparse initializer", True)
        self.nodes_of(start, end, 1, depth)

    def model(self) -> None:
        """ModelProto: graph 7, functions 25 (FunctionProto: node 7, attribute_proto 11)."""
        for number, wire, a, b in _fields(self.buf, 0, len(self.buf)):
            if wire != 2:
                continue
            if number == 7:
                self.graph(a, b, 0)
            elif number == 25:
                self.nodes_of(a, b, 7, 0)
                for n2, w2, a2, b2 in _fields(self.buf, a, b):
                    if n2 == 11 and w2 == 2:
                        self.attribute(a2, b2, 0)


def check_graph_bytes(path: str, data: bytes) -> None:
    """Refuse the graph file ``path`` (its bytes ``data``) when a tensor's data is external or
    an initializer has another type than float32, float16, int32 or int64; BundleError names
    the file."""
    try:
        _Scan(memoryview(data)).model()
    except _Malformed as e:
        raise BundleError(f"{path}: not a valid ONNX file (truncated?): {e}") from None
    except BundleError as e:
        raise BundleError(f"{path}: {e}") from None


def op_types(data: bytes) -> Set[str]:
    """The operator types of a checked graph file's top-level nodes (NodeProto op_type 4)."""
    buf, ops = memoryview(data), set()
    for number, wire, a, b in _fields(buf, 0, len(buf)):
        if number == 7 and wire == 2:
            for n2, w2, a2, b2 in _fields(buf, a, b):
                if n2 == 1 and w2 == 2:
                    ops.update(_text(buf, a3, b3) for n3, w3, a3, b3 in _fields(buf, a2, b2) if n3 == 4 and w3 == 2)
    return ops
