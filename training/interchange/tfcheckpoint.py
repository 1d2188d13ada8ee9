"""TensorFlow checkpoints (TensorBundle: ``<name>.index`` + ``<name>.data-<i>-of-<n>``) read
without TensorFlow.

The ``.index`` file is an SSTable (LevelDB's table format, as TensorFlow's ``lib/io/table``
writes it): data blocks of prefix-compressed ``key → value`` entries, an index block pointing
at them, and a 48-byte footer ending in the table magic. Keys are tensor names (the empty key is
the bundle header); values are ``BundleEntryProto`` messages: dtype, shape, shard, offset and
size of the tensor's little-endian bytes in the data file. TensorFlow writes bundle indexes
uncompressed; a compressed block is refused. The message class is declared here from
TensorFlow's ``tensor_bundle.proto`` field numbers (tensorboard's protos lack that file) on top
of tensorboard's ``TensorShapeProto``; nothing is unpickled or executed.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator, Mapping

import numpy as np
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from tensorboard.compat.proto import tensor_shape_pb2, types_pb2

TABLE_MAGIC = 0xDB4775248B80FB57
FOOTER_BYTES = 48
MAX_TENSOR_ELEMENTS = 50_000_000
DTYPES = {types_pb2.DT_FLOAT: np.dtype("<f4"), types_pb2.DT_INT32: np.dtype("<i4")}


class CheckpointFormatError(ValueError):
    """A ``.index``/``.data`` pair that is not a readable TensorFlow checkpoint."""


def _entry_class() -> type:
    """``BundleEntryProto`` (tensorflow/core/protobuf/tensor_bundle.proto), fields 1-6."""
    pool = descriptor_pool.Default()
    name = "racecraft/tensor_bundle_entry.proto"
    try:
        pool.FindFileByName(name)
    except KeyError:
        proto = descriptor_pb2.FileDescriptorProto(
            name=name, package="racecraft", syntax="proto3",
            dependency=[tensor_shape_pb2.DESCRIPTOR.name],
        )  # fmt: skip
        message = proto.message_type.add(name="BundleEntryProto")
        f = descriptor_pb2.FieldDescriptorProto
        for number, field, kind, type_name in (
            (1, "dtype", f.TYPE_INT32, None),  # an enum on the wire is a varint
            (2, "shape", f.TYPE_MESSAGE, ".tensorboard.TensorShapeProto"),
            (3, "shard_id", f.TYPE_INT32, None),
            (4, "offset", f.TYPE_INT64, None),
            (5, "size", f.TYPE_INT64, None),
            (6, "crc32c", f.TYPE_FIXED32, None),
        ):
            message.field.add(
                name=field, number=number, type=kind, label=f.LABEL_OPTIONAL,
                **({"type_name": type_name} if type_name else {}),
            )  # fmt: skip
        pool.Add(proto)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName("racecraft.BundleEntryProto"))


def _varint(data: bytes, pos: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        if pos >= len(data) or shift > 63:
            raise CheckpointFormatError("a truncated number in the index")
        byte = data[pos]
        value |= (byte & 0x7F) << shift
        pos, shift = pos + 1, shift + 7
        if byte < 0x80:
            return value, pos


def _block(data: bytes, handle: bytes) -> bytes:
    """The block a ``BlockHandle`` (offset, size) points at, checked uncompressed."""
    offset, pos = _varint(handle, 0)
    size, _ = _varint(handle, pos)
    if offset + size + 5 > len(data):
        raise CheckpointFormatError("a block lies outside the index file")
    if data[offset + size] != 0:
        raise CheckpointFormatError("compressed index blocks are not supported")
    return data[offset : offset + size]


def _entries(block: bytes) -> Iterator[tuple[bytes, bytes]]:
    """The ``key → value`` entries of one table block (keys share prefixes with the last)."""
    if len(block) < 4:
        raise CheckpointFormatError("a block is too short")
    (restarts,) = struct.unpack_from("<I", block, len(block) - 4)
    end = len(block) - 4 - 4 * restarts
    if end < 0:
        raise CheckpointFormatError("a block has a bad restart count")
    pos, key = 0, b""
    while pos < end:
        shared, pos = _varint(block, pos)
        unshared, pos = _varint(block, pos)
        length, pos = _varint(block, pos)
        if shared > len(key) or pos + unshared + length > end:
            raise CheckpointFormatError("a block entry runs past its block")
        key = key[:shared] + block[pos : pos + unshared]
        pos += unshared
        yield key, block[pos : pos + length]
        pos += length


def read_index(index: bytes) -> dict[str, object]:
    """Tensor name → ``BundleEntryProto`` of a ``.index`` file (the header entry left out)."""
    if len(index) < FOOTER_BYTES:
        raise CheckpointFormatError("the index file is too short")
    footer = index[-FOOTER_BYTES:]
    if struct.unpack("<Q", footer[-8:])[0] != TABLE_MAGIC:
        raise CheckpointFormatError("not a TensorFlow checkpoint index (no table magic)")
    _, pos = _varint(footer, _varint(footer, 0)[1])  # skip the metaindex handle
    index_handle = footer[pos:]
    entry_class = _entry_class()
    entries: dict[str, object] = {}
    for _, handle in _entries(_block(index, index_handle)):
        for key, value in _entries(_block(index, handle)):
            if key:
                entry = entry_class()
                try:
                    entry.ParseFromString(value)
                except Exception as exc:  # protobuf's DecodeError and friends
                    raise CheckpointFormatError(f"{key!r}: a bad entry ({exc})") from None
                entries[key.decode("utf-8", "replace")] = entry
    return entries


def read_checkpoint(index: bytes, shards: Mapping[int, bytes]) -> dict[str, np.ndarray]:
    """Every float32/int32 tensor of a checkpoint: name → array.

    ``shards`` maps a shard number to the bytes of ``.data-<shard>-of-<n>``. Tensors of other
    types (strings, int64 step counters...) are left out. Raises
    :class:`CheckpointFormatError` for a damaged file, a missing shard or an oversized tensor.
    """
    tensors: dict[str, np.ndarray] = {}
    for name, entry in read_index(index).items():
        dtype = DTYPES.get(entry.dtype)
        if dtype is None:
            continue
        shape = [d.size for d in entry.shape.dim]
        count = int(np.prod(shape, dtype=np.float64))
        if any(d < 0 for d in shape) or count > MAX_TENSOR_ELEMENTS:
            raise CheckpointFormatError(f"{name}: a tensor of shape {shape} is too large")
        if entry.shard_id not in shards:
            raise CheckpointFormatError(f"{name}: data shard {entry.shard_id} is missing")
        data = shards[entry.shard_id]
        if entry.size != count * dtype.itemsize or entry.offset + entry.size > len(data):
            raise CheckpointFormatError(f"{name}: its bytes do not fit shape {shape}")
        raw = data[entry.offset : entry.offset + entry.size]
        tensors[name] = np.frombuffer(raw, dtype).reshape(shape).astype(dtype.newbyteorder("="))
    return tensors
