"""Hostile model uploads for the import-bomb tests, made with the project's own protobuf
writers: a real car archive (a small Racecraft network exported as ``agent/model.pb``) with
nodes added to its graph, and graphs of ops a DeepRacer model never needs."""

from __future__ import annotations

import io
import tarfile

import numpy as np
from tensorboard.compat.proto import attr_value_pb2, graph_pb2, node_def_pb2, tensor_pb2, types_pb2
from tensorboard.compat.proto.tensor_shape_pb2 import TensorShapeProto

from tests.support import tar_gz
from training.interchange.carmodel import build_car_archive
from training.interchange.export import new_model
from training.interchange.integrity import masked_crc32c
from training.interchange.tfcheckpoint import TABLE_MAGIC, _entry_class
from training.interchange.tfgraph import GraphWriter
from training.rl.metadata import ModelMetadata, build_metadata
from training.rl.policies import LEAN

ACTIONS = [{"steering_angle": a, "speed": 1.0} for a in (-20, 0, 20)]


def small_metadata() -> ModelMetadata:
    return build_metadata(action_space=ACTIONS, sensor=["FRONT_FACING_CAMERA"], neural_network=LEAN)


def car_archive_files() -> dict[str, bytes]:
    """The files of a real car archive of a freshly built Racecraft model."""
    meta = small_metadata()
    data = build_car_archive(meta, new_model(meta))
    with tarfile.open(fileobj=io.BytesIO(data)) as tar:
        return {m.name: tar.extractfile(m).read() for m in tar.getmembers() if m.isfile()}


def fill(name: str, shape: list[int], value: float = 0.5) -> node_def_pb2.NodeDef:
    """A Const that stores one float and declares ``shape``: a few bytes that numpy would
    expand to every declared value."""
    dims = [TensorShapeProto.Dim(size=size) for size in shape]
    tensor = tensor_pb2.TensorProto(
        dtype=types_pb2.DT_FLOAT, tensor_shape=TensorShapeProto(dim=dims), float_val=[value]
    )
    node = node_def_pb2.NodeDef(op="Const", name=name)
    node.attr["dtype"].CopyFrom(attr_value_pb2.AttrValue(type=types_pb2.DT_FLOAT))
    node.attr["value"].CopyFrom(attr_value_pb2.AttrValue(tensor=tensor))
    return node


def op(kind: str, name: str, *inputs: str, **attrs: object) -> node_def_pb2.NodeDef:
    """A float32 node of op ``kind``; bool attributes as ``b``, lists as ints."""
    node = node_def_pb2.NodeDef(op=kind, name=name, input=list(inputs))
    node.attr["T"].CopyFrom(attr_value_pb2.AttrValue(type=types_pb2.DT_FLOAT))
    for key, value in attrs.items():
        if isinstance(value, bool):
            node.attr[key].CopyFrom(attr_value_pb2.AttrValue(b=value))
        else:
            node.attr[key].CopyFrom(
                attr_value_pb2.AttrValue(list=attr_value_pb2.AttrValue.ListValue(i=value))
            )
    return node


def with_nodes(files: dict[str, bytes], *nodes: node_def_pb2.NodeDef) -> bytes:
    """The car archive ``files`` with ``nodes`` added to its ``agent/model.pb``, as a tar.gz."""
    graph = graph_pb2.GraphDef()
    graph.ParseFromString(files["agent/model.pb"])
    graph.node.extend(nodes)
    return tar_gz({**files, "agent/model.pb": graph.SerializeToString()})


def matmul_chain(size: int, length: int, start: str = "x") -> graph_pb2.GraphDef:
    """``start @ A @ A @ ...``: a ``size``-square filled matrix ``A`` multiplied ``length``
    times, from the input ``x`` (one row per image) or from ``A`` itself."""
    writer = GraphWriter()
    writer.placeholder("x", [-1, size])
    writer.graph.node.append(fill("A", [size, size], 1.0 / size))  # rows stay at 1
    last = start
    for i in range(length):
        writer.graph.node.append(op("MatMul", f"mm{i}", last, "A", transpose_a=False))
        last = f"mm{i}"
    return writer.graph


def identity_chain(length: int) -> graph_pb2.GraphDef:
    writer = GraphWriter()
    writer.placeholder("x", [-1, 4])
    last = "x"
    for i in range(length):
        writer.graph.node.append(op("Identity", f"id{i}", last))
        last = f"id{i}"
    return writer.graph


def ones(shape: tuple[int, ...]) -> np.ndarray:
    return np.ones(shape, np.float32)


def _varint(value: int) -> bytes:
    out = bytearray()
    while True:
        byte, value = value & 0x7F, value >> 7
        out.append(byte | (0x80 if value else 0))
        if not value:
            return bytes(out)


def _table_block(entries: list[tuple[bytes, bytes]]) -> bytes:
    """One SSTable block, keys unshared, one restart point."""
    body = b"".join(_varint(0) + _varint(len(k)) + _varint(len(v)) + k + v for k, v in entries)
    return body + (0).to_bytes(4, "little") + (1).to_bytes(4, "little")


def checkpoint_index(tensors: dict[str, tuple[list[int], int, int]], shard: bytes = b"") -> bytes:
    """A TensorFlow ``.index`` (an SSTable of ``BundleEntryProto``) declaring float32 tensors
    ``name → (shape, offset, size)`` in shard 0, written by hand as TensorFlow lays it out,
    with the CRC-32C of each tensor's bytes in ``shard`` (where they lie in it)."""
    entry_class = _entry_class()
    entries = [(b"", b"")]
    for name, (shape, offset, size) in sorted(tensors.items()):
        entry = entry_class(dtype=types_pb2.DT_FLOAT, shard_id=0, offset=offset, size=size)
        entry.shape.dim.extend(TensorShapeProto.Dim(size=d) for d in shape)
        if offset + size <= len(shard):
            entry.crc32c = masked_crc32c(shard[offset : offset + size])
        entries.append((name.encode(), entry.SerializeToString()))
    data = _table_block(entries)
    index = _table_block([(b"\xff", _varint(0) + _varint(len(data)))])
    index_offset = len(data) + 5
    handles = _varint(0) + _varint(0) + _varint(index_offset) + _varint(len(index))
    footer = handles.ljust(40, b"\x00") + TABLE_MAGIC.to_bytes(8, "little")
    return data + _trailer(data) + index + _trailer(index) + footer


def _trailer(block: bytes) -> bytes:
    """A block's type (uncompressed) and masked CRC-32C."""
    return b"\x00" + masked_crc32c(block + b"\x00").to_bytes(4, "little")
