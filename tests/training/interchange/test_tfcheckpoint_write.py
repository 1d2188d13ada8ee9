"""TensorFlow checkpoints written without TensorFlow (:func:`write_checkpoint`): read back by
TensorFlow's own reader and by a ``Saver`` restore (with the ``[tf]`` extra), and by
Racecraft's reader."""

from __future__ import annotations

import numpy as np
import pytest

from training.interchange import tfcheckpoint
from training.interchange.tfcheckpoint import (
    CheckpointFormatError,
    read_checkpoint,
    read_index,
    write_checkpoint,
)


def tensors() -> dict[str, np.ndarray]:
    """Enough entries for several data blocks and restarts, names sharing long prefixes, a big
    tensor, scalars and the three dtypes a DeepRacer checkpoint holds."""
    rng = np.random.default_rng(7)
    found = {
        f"main_level/agent/main/online/network_{i % 2}/layer_{i:04d}/kernel": rng.normal(
            size=(i % 5 + 1, 3)
        ).astype(np.float32)
        for i in range(600)
    }
    found["main_level/agent/main/online/big/kernel"] = rng.normal(size=(600, 512)).astype(
        np.float32
    )
    found["main_level/agent/main/online/global_step"] = np.int64(1234)
    found["main_level/agent/main/online/beta1_power"] = np.float32(0.9)
    found["counts"] = np.arange(6, dtype=np.int32).reshape(2, 3)
    return found


@pytest.fixture(autouse=True)
def small_blocks(monkeypatch) -> None:
    """4 KiB blocks (TensorFlow's are 256 KiB), so a few hundred entries fill several."""
    monkeypatch.setattr(tfcheckpoint, "BLOCK_BYTES", 4096)


def test_racecrafts_reader_reads_every_tensor_back() -> None:
    written = tensors()
    index, data = write_checkpoint(written)
    assert len(index) > 3 * tfcheckpoint.BLOCK_BYTES  # several data blocks
    entries = read_index(index)
    assert set(entries) == set(written)
    read = read_checkpoint(index, {0: data})  # int64 counters are left out of what it reads
    assert set(read) == {k for k, v in written.items() if v.dtype != np.int64}
    for name in read:
        assert read[name].dtype == written[name].dtype
        assert np.array_equal(read[name], written[name]), name
    assert entries["main_level/agent/main/online/global_step"].size == 8


def test_the_same_tensors_give_the_same_bytes() -> None:
    assert write_checkpoint(tensors()) == write_checkpoint(dict(reversed(tensors().items())))


@pytest.mark.parametrize(
    "bad",
    [{"": np.zeros(2, np.float32)}, {"x": np.zeros(2, np.float64)}, {"x": np.array(["a"])}],
)
def test_what_a_checkpoint_cannot_hold_is_refused(bad) -> None:
    with pytest.raises(CheckpointFormatError, match="float32, int32 and int64"):
        write_checkpoint(bad)


def test_tensorflow_reads_it_checksums_and_all(tmp_path) -> None:
    tf = pytest.importorskip("tensorflow", reason="TensorFlow is in the [tf] test extra")
    written = tensors()
    index, data = write_checkpoint(written)
    (tmp_path / "3_Step-900.ckpt.index").write_bytes(index)
    (tmp_path / "3_Step-900.ckpt.data-00000-of-00001").write_bytes(data)
    reader = tf.train.load_checkpoint(str(tmp_path / "3_Step-900.ckpt"))
    shapes = reader.get_variable_to_shape_map()
    assert set(shapes) == set(written)
    for name, value in written.items():
        got = reader.get_tensor(name)
        assert got.dtype == value.dtype and np.array_equal(got, value), name
    # A graph-mode Saver, as DeepRacer's Coach restores its variables.
    v1 = tf.compat.v1
    with tf.Graph().as_default(), v1.Session() as session:
        big = v1.get_variable("main_level/agent/main/online/big/kernel", shape=(600, 512))
        step = v1.get_variable("main_level/agent/main/online/global_step", (), tf.int64)
        v1.train.Saver([big, step]).restore(session, str(tmp_path / "3_Step-900.ckpt"))
        restored_big, restored_step = session.run([big, step])
    assert restored_step == 1234
    assert np.array_equal(restored_big, written["main_level/agent/main/online/big/kernel"])
    # A flipped byte in a tensor is caught by TensorFlow's checksum, so the sums are TF's own.
    corrupt = bytearray(data)
    corrupt[100] ^= 0xFF
    (tmp_path / "3_Step-900.ckpt.data-00000-of-00001").write_bytes(bytes(corrupt))
    reader = tf.train.load_checkpoint(str(tmp_path / "3_Step-900.ckpt"))
    with pytest.raises(Exception, match="(?i)checksum|crc"):
        for name in written:
            reader.get_tensor(name)
