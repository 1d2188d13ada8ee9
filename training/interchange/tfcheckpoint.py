"""TensorFlow checkpoints (TensorBundle: ``<name>.index`` + ``<name>.data-<i>-of-<n>``) read
and written without TensorFlow.

The ``.index`` file is an SSTable (LevelDB's table format, as TensorFlow's ``lib/io/table``
writes it): data blocks of prefix-compressed ``key → value`` entries, an index block pointing
at them, and a 48-byte footer ending in the table magic. Keys are tensor names (the empty key is
the bundle header); values are ``BundleEntryProto`` messages: dtype, shape, shard, offset and
size of the tensor's little-endian bytes in the data file. TensorFlow writes bundle indexes
uncompressed; a compressed block is refused. The message class is declared here from
TensorFlow's ``tensor_bundle.proto`` field numbers (tensorboard's protos lack that file) on top
of tensorboard's ``TensorShapeProto``; nothing is unpickled or executed.

What is read is checked against the checksums the file records
(:func:`~training.interchange.integrity.masked_crc32c`): every block of the index as it is read
(its type byte and masked CRC-32C), and every tensor's bytes when the tensor is read (the
``crc32c`` of its ``BundleEntryProto``), as TensorFlow's ``BundleReader`` does; a flipped byte
or a wrong recorded sum is a :class:`CheckpointFormatError` naming the tensor and the file.

:func:`write_checkpoint` writes one shard as TensorFlow's ``BundleWriter`` does (the bundle
header under the empty key, entries in key order with the masked CRC-32C of each tensor's bytes,
256 KiB data blocks with a restart every 16 entries, an index block of one restart per entry,
an empty metaindex block, every block followed by its type byte and masked CRC-32C), so
TensorFlow's own reader (``tf.train.load_checkpoint``, a ``Saver``'s restore) reads it.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator, Mapping

import numpy as np
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from tensorboard.compat.proto import tensor_shape_pb2, types_pb2

from training.interchange.graphbudget import (
    LARGEST_REAL_TENSOR,
    MAX_GRAPH_VALUES,
    MAX_RANK,
    MAX_TENSOR_VALUES,
)
from training.interchange.integrity import masked_crc32c

TABLE_MAGIC = 0xDB4775248B80FB57
FOOTER_BYTES = 48
DTYPES = {types_pb2.DT_FLOAT: np.dtype("<f4"), types_pb2.DT_INT32: np.dtype("<i4")}
WRITTEN_DTYPES = DTYPES | {types_pb2.DT_INT64: np.dtype("<i8")}
BLOCK_BYTES = 262_144  # TensorFlow's table::Options().block_size
RESTART_INTERVAL = 16  # its block_restart_interval (the index block restarts at every entry)
BUNDLE_HEADER = b"\x08\x01\x1a\x02\x08\x01"
"""``BundleHeaderProto{num_shards: 1, endianness: LITTLE, version {producer: 1}}``, the
header TensorFlow writes under the empty key (``LITTLE`` is 0, so proto3 leaves it out)."""


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
    """The block a ``BlockHandle`` (offset, size) points at, checked uncompressed and against
    the masked CRC-32C of its contents and type byte that follows it."""
    offset, pos = _varint(handle, 0)
    size, _ = _varint(handle, pos)
    if offset + size + 5 > len(data):
        raise CheckpointFormatError("a block lies outside the index file")
    (recorded,) = struct.unpack_from("<I", data, offset + size + 1)
    if masked_crc32c(memoryview(data)[offset : offset + size + 1]) != recorded:
        raise CheckpointFormatError(
            f"the index file is damaged: the block at byte {offset:,} does not match its "
            "recorded CRC-32C"
        )
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
                except MemoryError:  # the import's memory limit, reported as such
                    raise
                except Exception as exc:  # protobuf's DecodeError and friends
                    raise CheckpointFormatError(f"{key!r}: a bad entry ({exc})") from None
                entries[key.decode("utf-8", "replace")] = entry
    return entries


def _declared(name: str, entry: object) -> tuple[list[int], int]:
    """The shape and value count a bundle entry declares, within the bounds."""
    shape = [d.size for d in entry.shape.dim]
    if entry.shape.unknown_rank or len(shape) > MAX_RANK or any(d < 0 for d in shape):
        raise CheckpointFormatError(f"the tensor {name!r} has no usable shape ({shape})")
    count = 1
    for size in shape:
        count *= size
    if count > MAX_TENSOR_VALUES:
        raise CheckpointFormatError(
            f"the tensor {name!r} declares {count:,} values; a DeepRacer model has at most "
            f"{MAX_TENSOR_VALUES:,} in one tensor (its biggest has {LARGEST_REAL_TENSOR:,})"
        )
    return shape, count


class CheckpointTensors(Mapping[str, np.ndarray]):
    """A checkpoint's float32/int32 tensors by name, each read from its shard on first use.

    Every entry was checked when the index was read (shape, bound, shard, bytes in range);
    a tensor's bytes are checked against the CRC-32C its entry records when it is read; the
    values read in all are bounded by
    :data:`~training.interchange.graphbudget.MAX_GRAPH_VALUES` (a checkpoint also holds Adam
    slots and target copies the import never reads, nor checksums). Raises
    :class:`CheckpointFormatError`.
    """

    def __init__(
        self,
        entries: dict[str, tuple],
        shards: Mapping[int, bytes],
        shard_names: Mapping[int, str] | None = None,
    ) -> None:
        self._entries, self._shards = entries, shards
        self._names = shard_names or {}
        self._read: dict[str, np.ndarray] = {}
        self._values = 0

    def __getitem__(self, name: str) -> np.ndarray:
        if name in self._read:
            return self._read[name]
        entry, dtype, shape, count = self._entries[name]
        if self._values + count > MAX_GRAPH_VALUES:
            raise CheckpointFormatError(
                f"the tensors read declare more than {MAX_GRAPH_VALUES:,} values in all "
                f"(at {name!r}); a DeepRacer model has at most {MAX_GRAPH_VALUES:,}"
            )
        self._values += count
        raw = memoryview(self._shards[entry.shard_id])[entry.offset : entry.offset + entry.size]
        if masked_crc32c(raw) != entry.crc32c:
            shard = self._names.get(entry.shard_id, f"data shard {entry.shard_id}")
            raise CheckpointFormatError(
                f"the tensor {name!r} does not match the CRC-32C its index records: "
                f"{shard} is damaged"
            )
        array = np.frombuffer(raw, dtype).reshape(shape).astype(dtype.newbyteorder("="))
        self._read[name] = array
        return array

    def __iter__(self) -> Iterator[str]:
        return iter(self._entries)

    def __len__(self) -> int:
        return len(self._entries)


def read_checkpoint(
    index: bytes, shards: Mapping[int, bytes], shard_names: Mapping[int, str] | None = None
) -> CheckpointTensors:
    """Every float32/int32 tensor of a checkpoint: name → array, read on first use.

    ``shards`` maps a shard number to the bytes of ``.data-<shard>-of-<n>``, ``shard_names``
    to its file name (for the messages). A tensor whose bytes do not match the CRC-32C its
    entry records is refused when it is read (:class:`CheckpointTensors`). Tensors of other
    types (strings, int64 step counters...) are left out. Every entry is checked here, before
    any tensor is built: its declared shape (at most
    :data:`~training.interchange.graphbudget.MAX_TENSOR_VALUES` values), its shard, and that
    its bytes lie inside it. Raises :class:`CheckpointFormatError` saying what is wrong.
    """
    entries: dict[str, tuple] = {}
    for name, entry in read_index(index).items():
        dtype = DTYPES.get(entry.dtype)
        if dtype is None:
            continue
        shape, count = _declared(name, entry)
        if entry.shard_id not in shards:
            raise CheckpointFormatError(f"{name}: data shard {entry.shard_id} is missing")
        data = shards[entry.shard_id]
        if (
            entry.size != count * dtype.itemsize
            or entry.offset < 0
            or entry.offset + entry.size > len(data)
        ):
            raise CheckpointFormatError(f"{name}: its bytes do not fit shape {shape}")
        entries[name] = (entry, dtype, shape, count)
    return CheckpointTensors(entries, shards, shard_names)


# --- writing ---------------------------------------------------------------------------------


_masked_crc = masked_crc32c  # LevelDB's masked CRC-32C, as tables and bundle entries store it


def _put_varint(value: int) -> bytes:
    out = bytearray()
    while value >= 0x80:
        out.append((value & 0x7F) | 0x80)
        value >>= 7
    out.append(value)
    return bytes(out)


class _BlockBuilder:
    """One table block: prefix-compressed entries, then the restart offsets and their count."""

    def __init__(self, restart_interval: int) -> None:
        self.interval = restart_interval
        self.buffer = bytearray()
        self.restarts = [0]
        self.count = 0
        self.last = b""

    def add(self, key: bytes, value: bytes) -> None:
        shared = 0
        if self.count < self.interval:
            limit = min(len(key), len(self.last))
            while shared < limit and key[shared] == self.last[shared]:
                shared += 1
        else:
            self.restarts.append(len(self.buffer))
            self.count = 0
        self.buffer += _put_varint(shared) + _put_varint(len(key) - shared)
        self.buffer += _put_varint(len(value)) + key[shared:] + value
        self.last = key
        self.count += 1

    def size(self) -> int:
        return len(self.buffer) + 4 * len(self.restarts) + 4

    def finish(self) -> bytes:
        restarts = struct.pack(f"<{len(self.restarts)}I", *self.restarts)
        return bytes(self.buffer) + restarts + struct.pack("<I", len(self.restarts))


class _TableWriter:
    """An SSTable of sorted keys as TensorFlow's ``table::TableBuilder`` lays it out
    (uncompressed). An index key is the last key of its block: every key of the block sorts
    at or before it, every key of the next block after it, which is all a lookup needs."""

    def __init__(self) -> None:
        self.out = bytearray()
        self.index = _BlockBuilder(1)
        self.block = _BlockBuilder(RESTART_INTERVAL)

    def _write_block(self, contents: bytes) -> bytes:
        handle = _put_varint(len(self.out)) + _put_varint(len(contents))
        self.out += contents + b"\x00" + struct.pack("<I", _masked_crc(contents + b"\x00"))
        return handle

    def _flush(self) -> None:
        if self.block.buffer:
            self.index.add(self.block.last, self._write_block(self.block.finish()))
            self.block = _BlockBuilder(RESTART_INTERVAL)

    def add(self, key: bytes, value: bytes) -> None:
        self.block.add(key, value)
        if self.block.size() >= BLOCK_BYTES:
            self._flush()

    def finish(self) -> bytes:
        self._flush()
        metaindex = self._write_block(_BlockBuilder(RESTART_INTERVAL).finish())
        index = self._write_block(self.index.finish())
        footer = (metaindex + index).ljust(FOOTER_BYTES - 8, b"\x00")
        return bytes(self.out) + footer + struct.pack("<Q", TABLE_MAGIC)


def write_checkpoint(tensors: Mapping[str, np.ndarray]) -> tuple[bytes, bytes]:
    """``(<name>.index, <name>.data-00000-of-00001)`` of a one-shard TensorFlow checkpoint
    holding ``tensors`` (variable name → float32, int32 or int64 array; a 0-d array is a
    scalar). Raises :class:`CheckpointFormatError` for another dtype or an empty name."""
    data = bytearray()
    entry_class = _entry_class()
    codes = {dtype: code for code, dtype in WRITTEN_DTYPES.items()}
    table = _TableWriter()
    table.add(b"", BUNDLE_HEADER)
    for name in sorted(tensors, key=lambda n: n.encode("utf-8")):
        array = np.asarray(tensors[name])
        code = codes.get(array.dtype.newbyteorder("<"))
        if not name or code is None:
            raise CheckpointFormatError(
                f"cannot write {name!r} ({array.dtype}): a checkpoint here holds named "
                "float32, int32 and int64 tensors"
            )
        raw = np.ascontiguousarray(array, array.dtype.newbyteorder("<")).tobytes()
        entry = entry_class(dtype=code, offset=len(data), size=len(raw), crc32c=_masked_crc(raw))
        entry.shape.SetInParent()  # a scalar still has a (dimensionless) shape, as TF writes
        for size in array.shape:
            entry.shape.dim.add(size=int(size))
        table.add(name.encode("utf-8"), entry.SerializeToString())
        data += raw
    return table.finish(), bytes(data)
