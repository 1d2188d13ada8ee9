"""What an import checks in the weights it reads: that they are the bytes their file recorded,
and that they are numbers.

- :func:`masked_crc32c`: LevelDB's masked CRC-32C, which a TensorFlow checkpoint records for
  every block of its ``.index`` and every tensor of its ``.data`` shards (TensorFlow's
  ``crc32c::Mask``). It comes from ``google-crc32c`` (a dependency), whose C implementation
  (SSE4.2 / ARM CRC instructions) reads several GB/s. Where its C extension cannot load, the
  package's own pure-Python fallback reads 0.6-4 MB/s (the 23 MB of a DeepRacer policy would
  take 6-40 s of the import's CPU budget), so :func:`crc32c_numpy` is used instead: the same
  table-driven CRC run on thousands of slices at once and the slices' CRCs combined, about
  70 MB/s (all measured in bench/bench_import_integrity.py on a shared 2-core machine).
- :func:`non_finite`: a NaN or an infinity in a weight makes every output of the policy NaN
  (or saturates it), and training from it never recovers; an import refuses such weights,
  naming the tensor (:func:`first_non_finite`).
"""

from __future__ import annotations

from collections.abc import Iterable

import google_crc32c
import numpy as np

CRC_MASK_DELTA = 0xA282EAD8  # TensorFlow's and LevelDB's kMaskDelta
CRC_POLYNOMIAL = 0x82F63B78  # Castagnoli's, bit-reversed
CRC_IMPLEMENTATION: str = google_crc32c.implementation
"""``c`` (hardware-accelerated) or ``python`` (the C extension did not load: then
:func:`crc32c_numpy` computes the sums)."""
NUMPY_LANES = 16_384  # slices summed at once by crc32c_numpy


def _byte_table() -> np.ndarray:
    table = np.zeros(256, np.uint32)
    for value in range(256):
        crc = value
        for _ in range(8):
            crc = (crc >> 1) ^ (CRC_POLYNOMIAL if crc & 1 else 0)
        table[value] = crc
    return table


_TABLE = _byte_table()
_TABLE_LIST = [int(v) for v in _TABLE]


def _after_zeros(length: int) -> list[list[int]]:
    """The CRC register's linear map "feed ``length`` zero bytes", as four byte tables: the
    register ``s`` becomes ``t[0][s & 255] ^ t[1][s >> 8 & 255] ^ t[2][...] ^ t[3][...]``."""
    basis = []
    for bit in range(32):
        state = 1 << bit
        for _ in range(length):
            state = _TABLE_LIST[state & 0xFF] ^ (state >> 8)
        basis.append(state)
    tables = []
    for byte in range(4):
        table = [0] * 256
        for value in range(1, 256):
            low = value & -value  # the lowest set bit, as a table index built from the others
            table[value] = table[value ^ low] ^ basis[8 * byte + low.bit_length() - 1]
        tables.append(table)
    return tables


def crc32c_numpy(data: bytes | bytearray | memoryview) -> int:
    """CRC-32C of ``data`` (what ``google_crc32c.value`` gives) with numpy: the bytes cut in
    up to :data:`NUMPY_LANES` slices, each slice's register computed side by side one byte
    column at a time, then the registers folded in order (a CRC is linear: the register after
    ``A + B`` is the one after ``A`` moved past ``len(B)`` zero bytes, xor ``B``'s own)."""
    buffer = np.frombuffer(data, np.uint8)
    width = max(1, -(-len(buffer) // NUMPY_LANES))
    whole = len(buffer) // width
    columns = np.ascontiguousarray(buffer[: whole * width].reshape(whole, width).T)
    registers = np.zeros(whole, np.uint32)
    for column in columns:
        registers = _TABLE[(registers ^ column) & 0xFF] ^ (registers >> 8)
    t0, t1, t2, t3 = _after_zeros(width)
    state = 0xFFFFFFFF
    for register in registers.tolist():
        state = (
            t0[state & 0xFF] ^ t1[(state >> 8) & 0xFF] ^ t2[(state >> 16) & 0xFF]
            ^ t3[state >> 24] ^ register
        )  # fmt: skip
    for byte in buffer[whole * width :].tolist():
        state = _TABLE_LIST[(state ^ byte) & 0xFF] ^ (state >> 8)
    return state ^ 0xFFFFFFFF


def masked_crc32c(data: bytes | bytearray | memoryview) -> int:
    """The masked CRC-32C of ``data``, as TensorFlow records it: the CRC rotated right by
    15 bits plus :data:`CRC_MASK_DELTA`, modulo 2**32."""
    if CRC_IMPLEMENTATION == "c":
        crc = google_crc32c.value(bytes(data) if isinstance(data, memoryview) else data)
    else:
        crc = crc32c_numpy(data)
    return (((crc >> 15) | (crc << 17)) + CRC_MASK_DELTA) & 0xFFFFFFFF


def non_finite(array: np.ndarray) -> str | None:
    """None when every value of ``array`` is finite (integers always are), else what it holds
    instead, to follow "holds": ``"2 NaN values (of 512)"``, ``"1 infinite value (of 64)"``,
    ``"only NaN (all 512 values)"``."""
    array = np.asarray(array)
    if array.dtype.kind not in "fc":
        return None
    finite = np.isfinite(array)
    if finite.all():
        return None
    nans = int(np.isnan(array).sum())
    infinite = int(finite.size - np.count_nonzero(finite)) - nans
    every = f"all {array.size:,} values" if array.size > 1 else "its one value"
    if nans == array.size:
        return f"only NaN ({every})"
    if infinite == array.size:
        return f"only infinities ({every})"
    parts = [f"{count:,} {kind} value{'s' if count > 1 else ''}"
             for count, kind in ((nans, "NaN"), (infinite, "infinite")) if count]  # fmt: skip
    return f"{' and '.join(parts)} (of {array.size:,})"


def first_non_finite(arrays: Iterable[tuple[str, np.ndarray]]) -> tuple[str, str] | None:
    """The first ``(name, what)`` of named arrays whose values are not all finite, or None."""
    for name, array in arrays:
        found = non_finite(array)
        if found is not None:
            return name, found
    return None
