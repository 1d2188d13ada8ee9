"""Imports check what they read (issue 47): a TensorFlow checkpoint's CRC-32Cs (of its index
blocks and of every tensor read) and that weights are finite numbers, on every import path:
the car archive's graph, the TensorFlow checkpoint, and model archives as .zip and .tar.gz
(Racecraft's, the AWS console's model folder, DeepRacer-on-AWS's). Each corrupt upload is made
from a real one (the project's own writers, and the AWS-trained sample models where they can be
had) with one thing broken, and is refused naming the file; the intact one still imports."""

from __future__ import annotations

import io
import json
import re
import tarfile
import zipfile

import google_crc32c
import numpy as np
import pytest
import torch
from tensorboard.compat.proto import graph_pb2
from tensorboard.util import tensor_util

from tests.support import tar_gz
from tests.training.interchange.carmodel_support import metadata_for
from tests.training.interchange.deepracer_support import (
    aws_samples,
    checkpoint_of,
    deepracer_style_graph,
)
from training import services
from training.interchange import integrity, tfcheckpoint
from training.interchange.archive import ArchiveError
from training.interchange.carmodel import build_car_archive, car_metadata, export_car_graph
from training.interchange.coachexport import coach_variables
from training.interchange.deepracer import import_car_archive, import_model_upload
from training.interchange.export import checkpoint_bytes, load_checkpoint, new_model
from training.interchange.integrity import crc32c_numpy, masked_crc32c, non_finite
from training.interchange.tfcheckpoint import read_index, write_checkpoint
from training.models import RacingModel
from training.rl.metadata import build_metadata
from training.rl.policies import AWS_SHALLOW, LEAN, SHALLOW

ACTIONS = [{"steering_angle": a, "speed": 1.0} for a in (-20, 0, 20)]
REWARD = b"def reward_function(params):\n    return 1.0\n"
HYPERPARAMETERS = json.dumps({"batch_size": 64, "lr": 0.0003, "num_epochs": 10}).encode()
CKPT = "model/3_Step-600.ckpt"
INDEX, DATA = f"{CKPT}.index", f"{CKPT}.data-00000-of-00001"
POLICY = "main_level/agent/main/online/network_1"
CONV0 = f"{POLICY}/FRONT_FACING_CAMERA/Conv2d_0/kernel"


def perturbed(metadata, seed: int):
    """A fresh model with every weight moved off its initial value."""
    model = new_model(metadata)
    generator = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for parameter in model.policy.parameters():
            parameter.add_(torch.randn(parameter.shape, generator=generator) * 0.02)
    return model


def zipped(files: dict[str, bytes]) -> bytes:
    """A .zip of ``files``, stored (DeepRacer-on-AWS's import takes .zip folders too)."""
    raw = io.BytesIO()
    with zipfile.ZipFile(raw, "w", zipfile.ZIP_STORED) as archive:
        for name, data in files.items():
            archive.writestr(name, data)
    return raw.getvalue()


def tarred(files: dict[str, bytes]) -> bytes:
    """An uncompressed .tar of ``files``: the checkpoint's 47 MB of random floats take seconds
    to gzip on a busy machine and compress to nothing, and the import reads a .tar alike."""
    raw = io.BytesIO()
    with tarfile.open(fileobj=raw, mode="w") as tar:
        for name, data in files.items():
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
    return raw.getvalue()


PACK = {"tar.gz": tar_gz, "zip": zipped}


def flipped(data: bytes, at: int) -> bytes:
    corrupt = bytearray(data)
    corrupt[at] ^= 0x5A
    return bytes(corrupt)


def refused(upload: bytes, *parts: str) -> str:
    """The message an import of ``upload`` is refused with; it holds every part, in order."""
    with pytest.raises(ArchiveError) as error:
        import_model_upload(upload)
    message = str(error.value)
    assert re.search(".*".join(re.escape(p) for p in parts), message), message
    return message


# --- the TensorFlow checkpoint (DeepRacer-on-AWS's model folder) ------------------------------


@pytest.fixture(scope="module")
def shallow():
    """DeepRacer's 3-layer network (the one its checkpoints hold) with perturbed weights."""
    metadata = build_metadata(action_space=ACTIONS, neural_network=AWS_SHALLOW)
    return metadata, perturbed(metadata, seed=5)


@pytest.fixture(scope="module")
def checkpoint(shallow) -> tuple[bytes, bytes]:
    """The model as the project's own writer writes DeepRacer's checkpoint (index, data)."""
    metadata, model = shallow
    return write_checkpoint(coach_variables(model, metadata))


def checkpoint_folder(metadata, index: bytes, data: bytes) -> dict[str, bytes]:
    """The model folder DeepRacer-on-AWS's import page takes: the checkpoint, no graph."""
    return {
        "model_metadata.json": car_metadata(metadata),
        "hyperparameters.json": HYPERPARAMETERS,
        "reward_function.py": REWARD,
        "model/.coach_checkpoint": CKPT.removeprefix("model/").encode(),
        INDEX: index,
        DATA: data,
    }


def test_an_intact_checkpoint_still_imports_as_the_same_policy(shallow, checkpoint) -> None:
    metadata, model = shallow
    imported = import_model_upload(tarred(checkpoint_folder(metadata, *checkpoint)))
    assert imported.source == INDEX
    back = load_checkpoint(imported.checkpoint_bytes, imported.metadata)
    frames = torch.rand(2, 1, 120, 160, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        expected = model.policy.get_distribution(frames).distribution.probs
        got = back.policy.get_distribution(frames).distribution.probs
    torch.testing.assert_close(got, expected, atol=1e-5, rtol=0)


def test_flipped_data_bytes_fail_the_tensors_crc(shallow, checkpoint) -> None:
    metadata, _ = shallow
    index, data = checkpoint
    entry = read_index(index)[CONV0]
    corrupt = flipped(data, entry.offset + entry.size // 2)
    refused(
        tarred(checkpoint_folder(metadata, index, corrupt)),
        f"{INDEX}: the tensor '{CONV0}' does not match the CRC-32C its index records: "
        f"{DATA} is damaged",
    )


def test_a_wrong_recorded_crc_is_refused(shallow, monkeypatch) -> None:
    """A writer that records a wrong sum for one tensor (its index otherwise sound)."""
    metadata, model = shallow
    variables = coach_variables(model, metadata)
    target = np.ascontiguousarray(variables[CONV0], "<f4").tobytes()
    right = tfcheckpoint._masked_crc
    monkeypatch.setattr(
        tfcheckpoint, "_masked_crc", lambda data: right(data) ^ (bytes(data) == target)
    )
    index, data = write_checkpoint(variables)
    monkeypatch.undo()
    assert read_index(index)[CONV0].crc32c == masked_crc32c(target) ^ 1  # the blocks are sound
    refused(
        tarred(checkpoint_folder(metadata, index, data)),
        f"{INDEX}: the tensor '{CONV0}' does not match the CRC-32C its index records",
    )


def test_a_damaged_index_block_is_refused(shallow, checkpoint) -> None:
    metadata, _ = shallow
    index, data = checkpoint
    refused(
        tarred(checkpoint_folder(metadata, flipped(index, 40), data)),
        f"{INDEX}: the index file is damaged: the block at byte 0 does not match its recorded "
        "CRC-32C",
    )


@pytest.mark.parametrize("pack", [tarred, zipped])
def test_all_nan_weights_in_a_checkpoint_are_refused(shallow, pack) -> None:
    """Every variable NaN, its sums right: the checkpoint is sound, its weights are not."""
    metadata, model = shallow
    variables = coach_variables(model, metadata)
    index, data = write_checkpoint({k: np.full_like(v, np.nan) for k, v in variables.items()})
    count = read_index(index)[CONV0].size // 4
    refused(
        pack(checkpoint_folder(metadata, index, data)),
        f"{INDEX}: the tensor '{CONV0}' holds only NaN (all {count:,} values); a model's "
        "weights must be finite numbers",
    )


@pytest.mark.slow
def test_a_checkpoint_tensorflow_wrote_is_checked_too() -> None:
    """A TF1 ``Saver``'s checkpoint (the ``[tf]`` extra): intact it imports, so the sums are
    read as TensorFlow writes them; a flipped byte in its policy is refused."""
    meta = metadata_for(SHALLOW, "FRONT_FACING_CAMERA", "ppo_discrete")
    graph = deepracer_style_graph("FRONT_FACING_CAMERA", "ppo_discrete", 10, seed=4)
    files = checkpoint_of(graph, name=CKPT)
    folder = {**checkpoint_folder(meta, files[INDEX], files[DATA]), **files}
    assert import_model_upload(tarred(folder)).source == INDEX
    entry = read_index(files[INDEX])[CONV0]
    folder[DATA] = flipped(files[DATA], entry.offset + 3)
    refused(tarred(folder), f"{INDEX}: the tensor '{CONV0}' does not match the CRC-32C")


# --- the car archive and frozen graphs --------------------------------------------------------


@pytest.fixture(scope="module")
def lean():
    metadata = build_metadata(action_space=ACTIONS, neural_network=LEAN)
    return metadata, perturbed(metadata, seed=3)


def with_value(model, metadata, value: float, count: int = 1):
    """A copy of ``model`` whose first convolution's first ``count`` weights are ``value``."""
    copy = load_checkpoint(checkpoint_bytes(model), metadata)
    conv = next(m for m in copy.policy.features_extractor.cnn if isinstance(m, torch.nn.Conv2d))
    with torch.no_grad():
        conv.weight.view(-1)[:count] = value
    return copy


def test_an_intact_car_archive_still_imports(lean) -> None:
    metadata, model = lean
    imported = import_car_archive(build_car_archive(metadata, model))
    assert imported.metadata.neural_network == LEAN


@pytest.mark.parametrize("value", [float("inf"), float("-inf"), float("nan")])
def test_a_car_archive_with_a_non_finite_constant_is_refused(lean, value) -> None:
    metadata, model = lean
    upload = build_car_archive(metadata, with_value(model, metadata, value, count=2))
    what = "2 NaN values" if np.isnan(value) else "2 infinite values"
    with pytest.raises(ArchiveError, match=r"^agent/model\.pb: the constant '.*/kernel' holds "
                       + what + r" \(of [\d,]+\); a model's weights must be finite"):  # fmt: skip
        import_car_archive(upload)
    refused(upload, "agent/model.pb: the constant", what)  # the path every upload takes


def test_weights_that_overflow_once_the_input_scaling_is_folded_are_refused(lean) -> None:
    """Every constant finite, but the graph divides its input by 1e-40: the first layer's
    weights times 255 / 1e-40 are past float32."""
    metadata, model = lean
    graph = graph_pb2.GraphDef()
    graph.ParseFromString(export_car_graph(model, metadata))
    (divisor,) = [n for n in graph.node if n.name.endswith("/truediv/y")]
    divisor.attr["value"].tensor.CopyFrom(
        tensor_util.make_tensor_proto(np.float32(1e-40), dtype=np.float32)
    )
    upload = tar_gz(
        {"agent/model.pb": graph.SerializeToString(), "model_metadata.json": car_metadata(metadata)}
    )
    refused(upload, "agent/model.pb: the policy's ", "holds only infinities", "once built")


# --- model archives (.zip and .tar.gz) --------------------------------------------------------


@pytest.mark.parametrize("pack", sorted(PACK))
def test_nan_weights_in_racecrafts_own_model_archive_are_refused(lean, pack) -> None:
    metadata, model = lean
    folder = {
        "model/model_metadata.json": metadata.dumps(),
        "ip/hyperparameters.json": HYPERPARAMETERS,
        "reward_function.py": REWARD,
        "model/best.zip": checkpoint_bytes(model),
    }
    assert import_model_upload(PACK[pack](folder)).checkpoint_name == "best"
    folder["model/best.zip"] = checkpoint_bytes(with_value(model, metadata, float("nan"), 3))
    refused(
        PACK[pack](folder),
        "model/best.zip: the weight 'features_extractor.cnn.1.weight' holds 3 NaN values (of",
    )


@pytest.mark.parametrize("pack", sorted(PACK))
def test_nan_weights_in_a_deepracer_model_folders_graph_are_refused(lean, pack) -> None:
    """The AWS console's model folder: the frozen graph DeepRacer writes beside a checkpoint."""
    metadata, model = lean
    folder = {
        "model/model_metadata.json": car_metadata(metadata),
        "ip/hyperparameters.json": HYPERPARAMETERS,
        "reward_function.py": REWARD,
        "model/model_3.pb": export_car_graph(model, metadata),
    }
    assert import_model_upload(PACK[pack](folder)).source == "model/model_3.pb"
    bad = with_value(model, metadata, float("nan"))
    folder["model/model_3.pb"] = export_car_graph(bad, metadata)
    refused(PACK[pack](folder), "model/model_3.pb: the constant '", "' holds 1 NaN value (of")


def nan_in_constant(graph: bytes, suffix: str) -> bytes:
    """``graph`` with the Const named ``...<suffix>`` all NaN (its shape kept)."""
    parsed = graph_pb2.GraphDef()
    parsed.ParseFromString(graph)
    (node,) = [n for n in parsed.node if n.op == "Const" and n.name.endswith(suffix)]
    value = tensor_util.make_ndarray(node.attr["value"].tensor)
    node.attr["value"].tensor.CopyFrom(
        tensor_util.make_tensor_proto(np.full(value.shape, np.nan, np.float32))
    )
    return parsed.SerializeToString()


@pytest.mark.slow
@pytest.mark.parametrize("pack", sorted(PACK))
def test_the_real_aws_models_corrupted_are_refused(pack) -> None:
    """The AWS-trained sample model (deepracer-utils'), intact then with NaN in one kernel."""
    samples = aws_samples()
    graph = samples.graphs[30]
    car = {"agent/model.pb": graph, "model_metadata.json": samples.metadata}
    assert import_model_upload(PACK[pack](car)).metadata.neural_network == AWS_SHALLOW
    car["agent/model.pb"] = nan_in_constant(graph, "Conv2d_0/kernel")
    refused(PACK[pack](car), "agent/model.pb: the constant '", "Conv2d_0/kernel' holds only NaN")
    folder = {
        "model/model_metadata.json": samples.metadata,
        "ip/hyperparameters.json": HYPERPARAMETERS,
        "reward_function.py": REWARD,
        "model/model_30.pb": nan_in_constant(graph, "Dense_0/kernel"),
    }
    refused(PACK[pack](folder), "model/model_30.pb: the constant '", "Dense_0/kernel' holds")


# --- through the service: nothing is saved ----------------------------------------------------


@pytest.mark.django_db
@pytest.mark.usefixtures("store_dir")
def test_a_damaged_checkpoint_leaves_no_model_behind(alice, shallow, checkpoint) -> None:
    """The import runs in its bounded child process; the refusal reaches the user naming the
    file, and no model (Ready or otherwise) is saved."""
    metadata, _ = shallow
    index, data = checkpoint
    entry = read_index(index)[CONV0]
    upload = tarred(checkpoint_folder(metadata, index, flipped(data, entry.offset)))
    with pytest.raises(services.ServiceError) as error:
        services.model_import(owner=alice, name="damaged", upload=upload)
    assert error.value.field == "archive"
    assert error.value.sentence.startswith(
        f"{INDEX}: the tensor '{CONV0}' does not match the CRC-32C its index records"
    )
    assert not RacingModel.objects.filter(owner=alice).exists()


# --- the checks themselves --------------------------------------------------------------------


def test_the_masked_crc_is_tensorflows() -> None:
    """CRC-32C("123456789") is 0xE3069283 (RFC 3720); TensorFlow's crc32c::Mask of it."""
    crc = 0xE3069283
    assert masked_crc32c(b"123456789") == (((crc >> 15) | (crc << 17)) + 0xA282EAD8) % 2**32
    assert masked_crc32c(memoryview(b"123456789")) == masked_crc32c(b"123456789")


@pytest.mark.parametrize("size", [0, 1, 9, 16_383, 16_385, 100_003, 3 * 16_384 * 7 + 5])
def test_the_numpy_crc_is_google_crc32cs(size, monkeypatch) -> None:
    """The fallback where google-crc32c's C extension does not load gives the same sums."""
    data = np.random.default_rng(size).integers(0, 256, size, np.uint8).tobytes()
    assert crc32c_numpy(data) == google_crc32c.value(data)
    expected = masked_crc32c(data)
    monkeypatch.setattr(integrity, "CRC_IMPLEMENTATION", "python")
    assert masked_crc32c(memoryview(data)) == expected


def test_what_is_not_finite_is_counted() -> None:
    assert non_finite(np.ones((2, 3), np.float32)) is None
    assert non_finite(np.arange(4)) is None
    assert non_finite(np.array([1.0, np.nan, np.inf, -np.inf])) == (
        "1 NaN value and 2 infinite values (of 4)"
    )
    assert non_finite(np.full(1000, np.nan)) == "only NaN (all 1,000 values)"
    assert non_finite(np.float32(np.inf)) == "only infinities (its one value)"
