"""Importing uploaded virtual models: a good one round-trips, bad ones say what is wrong."""

from __future__ import annotations

import gzip
import io
import json
import tarfile
import zipfile
from collections.abc import Callable

import pytest
import torch

from tests.support import tar_gz
from training.interchange.archive import (
    ArchiveError,
    ImportLimits,
    import_virtual_model,
    read_archive,
)
from training.interchange.export import (
    build_virtual_model_archive,
    checkpoint_bytes,
    load_checkpoint,
)
from training.rl.metadata import build_metadata

REWARD = "def reward_function(params):\n    return float(params['progress']) / 100.0\n"


@pytest.fixture(scope="module")
def files(ppo_discrete) -> dict[str, bytes]:
    """A good model folder built from a real tiny PPO model."""
    return {
        "model/model_metadata.json": ppo_discrete.metadata.dumps(),
        "ip/hyperparameters.json": json.dumps({"batch_size": 32, "lr": 0.0001}).encode(),
        "reward_function.py": REWARD.encode(),
        "model/best.zip": checkpoint_bytes(ppo_discrete.model),
        "metrics/TrainingMetrics.json": b'{"metrics": [{"reward_score": 3}]}',
    }


def zip_of(entries: dict[str, bytes]) -> bytes:
    raw = io.BytesIO()
    with zipfile.ZipFile(raw, "w", zipfile.ZIP_DEFLATED) as archive:
        for name, data in entries.items():
            archive.writestr(name, data)
    return raw.getvalue()


def special(name: str, kind: bytes, linkname: str = "") -> Callable[[tarfile.TarFile], None]:
    def add(tar: tarfile.TarFile) -> None:
        info = tarfile.TarInfo(name)
        info.type, info.linkname = kind, linkname
        tar.addfile(info)

    return add


# --- good archives ----------------------------------------------------------------------------


def test_roundtrip_of_an_exported_virtual_model(files, ppo_discrete) -> None:
    imported = import_virtual_model(build_virtual_model_archive(files))
    assert imported.metadata == ppo_discrete.metadata
    assert imported.hyperparameters.batch_size == 32 and imported.hyperparameters.lr == 0.0001
    assert imported.reward_function == REWARD
    assert imported.checkpoint_name == "best"
    assert imported.extra_files == {
        "metrics/TrainingMetrics.json": files["metrics/TrainingMetrics.json"]
    }
    again = load_checkpoint(imported.checkpoint_bytes, imported.metadata)
    for key, value in ppo_discrete.model.policy.state_dict().items():
        assert torch.equal(again.policy.state_dict()[key], value)


def test_zip_with_top_folder_and_flat_layout(files, sac_continuous) -> None:
    flat = {
        "my-model/model_metadata.json": sac_continuous.metadata.dumps(),
        "my-model/hyperparameters.json": b"{}",
        "my-model/reward_function.py": REWARD.encode(),
        "my-model/model/12_Step-300.zip": checkpoint_bytes(sac_continuous.model),
        "my-model/training_params.yaml": b"WORLD_NAME: racecraft_summit\n",
        "my-model/": b"",
    }
    imported = import_virtual_model(io.BytesIO(zip_of(flat)))
    assert imported.metadata.training_algorithm == "sac"
    assert imported.hyperparameters.discount_factor == 0.99  # SAC defaults
    assert imported.checkpoint_name == "12_Step-300"
    assert imported.extra_files == {"training_params.yaml": b"WORLD_NAME: racecraft_summit\n"}


def test_checkpoints_index_chooses(files) -> None:
    index = {"best_checkpoint": {"name": "7_Step-100"}, "last_checkpoint": {"name": "9_Step-200"}}
    upload = {
        **{k: v for k, v in files.items() if k != "model/best.zip"},
        "model/7_Step-100.zip": files["model/best.zip"],
        "model/9_Step-200.zip": b"not even a zip",
        "model/deepracer_checkpoints.json": json.dumps(index).encode(),
    }
    assert import_virtual_model(tar_gz(upload)).checkpoint_name == "7_Step-100"


def test_plain_tar_and_dot_slash_names(files) -> None:
    raw = io.BytesIO()
    with tarfile.open(fileobj=raw, mode="w") as tar:
        for name, data in files.items():
            info = tarfile.TarInfo("./" + name)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
    assert import_virtual_model(raw.getvalue()).checkpoint_name == "best"


# --- bad archives: each names the problem -----------------------------------------------------


def without(files: dict[str, bytes], *names: str) -> dict[str, bytes]:
    return {k: v for k, v in files.items() if k not in names}


def bad_cases(files: dict[str, bytes]) -> dict[str, tuple[bytes, str]]:
    meta = json.loads(files["model/model_metadata.json"])
    tf = {
        **without(files, "model/best.zip"),
        "model/13_Step-25173.ckpt.index": b"x",
        "model/13_Step-25173.ckpt.meta": b"x",
        "model/.coach_checkpoint": b"13_Step-25173.ckpt",
    }
    five = build_metadata(
        action_space=[{"steering_angle": a, "speed": 1} for a in (-20, -10, 0, 10, 20)],
        neural_network="RACECRAFT_LEAN_CNN",
    )
    checkpoint = files["model/best.zip"]
    flipped = bytearray(checkpoint)  # damage the tensors inside policy.pth: CRC mismatch
    start = checkpoint.index(b"policy.pth") + 200
    flipped[start : start + 64] = bytes(b ^ 0xFF for b in flipped[start : start + 64])
    return {
        "traversal": (tar_gz({**files, "../../etc/cron.d/evil": b"x"}), "'..' is not allowed"),
        "traversal in zip": (zip_of({**files, "model/../../evil.py": b"x"}), "'..' is not allowed"),
        "absolute path": (tar_gz({**files, "/etc/passwd": b"x"}), "absolute paths"),
        "windows path": (zip_of({**files, "model\\..\\evil": b"x"}), "backslashes"),
        "symlink": (
            tar_gz(files, special("model/link", tarfile.SYMTYPE, "/etc/passwd")),
            "links are not allowed",
        ),
        "hardlink": (
            tar_gz(files, special("model/hard", tarfile.LNKTYPE, "reward_function.py")),
            "links are not allowed",
        ),
        "device": (tar_gz(files, special("model/dev", tarfile.CHRTYPE)), "only regular files"),
        "fifo": (tar_gz(files, special("model/fifo", tarfile.FIFOTYPE)), "only regular files"),
        "duplicate": (
            tar_gz(
                files, lambda t: t.addfile(_info("./reward_function.py", 3), io.BytesIO(b"bad"))
            ),
            "reward_function.py: the archive holds this name twice",
        ),
        "not an archive": (b"hello, this is text" * 30, "not a .tar.gz, .tar or .zip"),
        "truncated gzip": (tar_gz(files)[:5000], "damaged"),
        "missing metadata": (
            tar_gz(without(files, "model/model_metadata.json")),
            "model/model_metadata.json is missing",
        ),
        "missing reward": (
            tar_gz(without(files, "reward_function.py")),
            "reward_function.py is missing",
        ),
        "missing hyperparameters": (
            tar_gz(without(files, "ip/hyperparameters.json")),
            "ip/hyperparameters.json is missing",
        ),
        "missing checkpoint": (tar_gz(without(files, "model/best.zip")), "no checkpoint to import"),
        "bad JSON": (
            tar_gz({**files, "ip/hyperparameters.json": b"{batch_size: 64"}),
            "ip/hyperparameters.json: not valid JSON",
        ),
        "bad hyperparameters": (
            tar_gz({**files, "ip/hyperparameters.json": b'{"batch_size": 100}'}),
            "ip/hyperparameters.json: batch_size: must be one of",
        ),
        "bad metadata": (
            tar_gz(
                {
                    **files,
                    "model/model_metadata.json": json.dumps(
                        {**meta, "sensor": ["FRONT_FACING_CAMERA", "SONAR"]}
                    ).encode(),
                }
            ),
            "model/model_metadata.json: sensor: unknown sensor 'SONAR'",
        ),
        "metadata not JSON": (
            tar_gz({**files, "model/model_metadata.json": b"\x89PNG"}),
            "model/model_metadata.json: model_metadata.json: is not",
        ),
        "mismatched action space": (
            tar_gz({**files, "model/model_metadata.json": five.dumps()}),
            "model/best.zip: the checkpoint has 10 discrete actions but "
            "model_metadata.json lists 5",
        ),
        "mismatched algorithm": (
            tar_gz(
                {
                    **files,
                    "model/model_metadata.json": json.dumps(
                        {
                            **meta,
                            "action_space": {
                                "steering_angle": {"low": -30, "high": 30},
                                "speed": {"low": 1, "high": 2},
                            },
                            "action_space_type": "continuous",
                            "training_algorithm": "sac",
                        }
                    ).encode(),
                }
            ),
            "model/best.zip: the checkpoint is a PPO model",
        ),
        "mismatched camera": (
            tar_gz(
                {
                    **files,
                    "model/model_metadata.json": json.dumps(
                        {**meta, "sensor": ["STEREO_CAMERAS"]}
                    ).encode(),
                }
            ),
            "takes 1-channel images but the sensor STEREO_CAMERAS gives 2",
        ),
        "mismatched network": (
            tar_gz(
                {
                    **files,
                    "model/model_metadata.json": json.dumps(
                        {**meta, "neural_network": "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW"}
                    ).encode(),
                }
            ),
            "do not fit neural_network DEEP_CONVOLUTIONAL_NETWORK_SHALLOW",
        ),
        "non-UTF-8 reward": (
            tar_gz(
                {
                    **files,
                    "reward_function.py": b"def reward_function(p):\n    return 1  # caf\xe9\n",
                }
            ),
            "reward_function.py: not UTF-8",
        ),
        "huge reward": (
            tar_gz({**files, "reward_function.py": b"#" * 140_001}),
            "reward_function.py: longer than 140,000 characters",
        ),
        "TF checkpoint only": (
            tar_gz(tf),
            "DeepRacer TensorFlow model, which Racecraft cannot load; "
            "only models exported from Racecraft",
        ),
        "truncated checkpoint zip": (
            tar_gz({**files, "model/best.zip": checkpoint[: len(checkpoint) // 2]}),
            "model/best.zip: not a readable zip file",
        ),
        "damaged checkpoint tensors": (
            tar_gz({**files, "model/best.zip": bytes(flipped)}),
            "model/best.zip: not a readable zip file",
        ),
        "checkpoint not a zip": (
            tar_gz({**files, "model/best.zip": b"PK\x03\x04garbage"}),
            "model/best.zip: not a readable zip file",
        ),
        "checkpoint without policy": (
            tar_gz({**files, "model/best.zip": zip_of({"data": b"{}"})}),
            "model/best.zip: not a stable-baselines3 model",
        ),
        "pickle in checkpoint": (
            tar_gz({**files, "model/best.zip": zip_of({"policy.pth": _evil_pickle()})}),
            "model/best.zip: the tensors do not load",
        ),
        "two checkpoints, no index": (
            tar_gz({**without(files, "model/best.zip"), "model/a.zip": b"1", "model/b.zip": b"2"}),
            "deepracer_checkpoints.json is needed",
        ),
    }


def _info(name: str, size: int) -> tarfile.TarInfo:
    info = tarfile.TarInfo(name)
    info.size = size
    return info


def _evil_pickle() -> bytes:
    """A .pth whose unpickling would run code: weights_only loading must refuse it."""
    import pickle

    class Evil:
        def __reduce__(self):  # noqa: ANN204
            return (print, ("pwned",))

    buffer = io.BytesIO()
    torch.save({"x": 1}, buffer)  # a real torch zip, then swap the pickle for an evil one
    with zipfile.ZipFile(io.BytesIO(buffer.getvalue())) as source:
        names = source.namelist()
        out = io.BytesIO()
        with zipfile.ZipFile(out, "w") as target:
            for name in names:
                data = source.read(name)
                if name.endswith("data.pkl"):
                    data = pickle.dumps(Evil(), protocol=2)
                target.writestr(name, data)
    return out.getvalue()


CASES = [
    "traversal",
    "traversal in zip",
    "absolute path",
    "windows path",
    "symlink",
    "hardlink",
    "device",
    "fifo",
    "duplicate",
    "not an archive",
    "truncated gzip",
    "missing metadata",
    "missing reward",
    "missing hyperparameters",
    "missing checkpoint",
    "bad JSON",
    "bad hyperparameters",
    "bad metadata",
    "metadata not JSON",
    "mismatched action space",
    "mismatched algorithm",
    "mismatched camera",
    "mismatched network",
    "non-UTF-8 reward",
    "huge reward",
    "TF checkpoint only",
    "truncated checkpoint zip",
    "damaged checkpoint tensors",
    "checkpoint not a zip",
    "checkpoint without policy",
    "pickle in checkpoint",
    "two checkpoints, no index",
]


@pytest.fixture(scope="module")
def cases(files) -> dict[str, tuple[bytes, str]]:
    built = bad_cases(files)
    assert sorted(built) == sorted(CASES)
    return built


@pytest.mark.parametrize("case", CASES)
def test_bad_archive(case: str, cases, capfd) -> None:
    upload, words = cases[case]
    with pytest.raises(ArchiveError) as info:
        import_virtual_model(upload)
    assert words in str(info.value)
    assert "pwned" not in capfd.readouterr().out


def test_upload_size_limit(files) -> None:
    upload = tar_gz(files)
    limits = ImportLimits(max_upload_bytes=len(upload) - 1)
    with pytest.raises(ArchiveError, match="larger than"):
        import_virtual_model(upload, limits)
    with pytest.raises(ArchiveError, match="larger than"):
        import_virtual_model(io.BytesIO(upload), limits)  # a stream is not read past the limit
    with pytest.raises(ArchiveError, match="empty"):
        import_virtual_model(b"")


@pytest.mark.parametrize("packer", [tar_gz, zip_of])
def test_bomb_guard(packer) -> None:
    """10 MB of zeros compresses to ~10 KB; the uncompressed limit stops it."""
    bomb = packer({"reward_function.py": b"0" * 10_000_000})
    assert len(bomb) < 100_000
    with pytest.raises(ArchiveError, match="once uncompressed"):
        read_archive(bomb, ImportLimits(max_uncompressed_bytes=1_000_000))


def test_gzip_bomb_in_tar_headers() -> None:
    """A 20 MB PAX header (tarfile reads headers whole, before any size check of ours) is
    stopped by the cap on the decompressed stream."""
    raw = io.BytesIO()
    with tarfile.open(fileobj=raw, mode="w", format=tarfile.PAX_FORMAT) as tar:
        info = _info("reward_function.py", 1)
        info.pax_headers = {"comment": "0" * 20_000_000}
        tar.addfile(info, io.BytesIO(b"x"))
    bomb = gzip.compress(raw.getvalue())
    assert len(bomb) < 100_000
    with pytest.raises(ArchiveError, match="too much data once uncompressed"):
        read_archive(bomb, ImportLimits(max_uncompressed_bytes=1_000_000, max_members=10))


def test_gzip_of_zeros_reads_as_empty() -> None:
    """Zero blocks end a tar at once: nothing more is decompressed, nothing is found."""
    assert read_archive(gzip.compress(b"\x00" * 20_000_000)) == {}


def test_zip_lying_about_sizes() -> None:
    """Sizes in a zip's directory are checked before anything is decompressed, and the data
    cannot exceed them."""
    honest = zip_of({"a.txt": b"A" * 5000})
    with pytest.raises(ArchiveError, match="once uncompressed"):
        read_archive(honest, ImportLimits(max_uncompressed_bytes=4999))
    assert read_archive(honest) == {"a.txt": b"A" * 5000}


@pytest.mark.parametrize("packer", [tar_gz, zip_of])
def test_member_count_limit(packer) -> None:
    many = packer({f"metrics/{i}.json": b"{}" for i in range(30)})
    with pytest.raises(ArchiveError, match="more than 20 files"):
        read_archive(many, ImportLimits(max_members=20))


def test_encrypted_zip_member_refused() -> None:
    raw = bytearray(zip_of({"reward_function.py": b"x"}))
    # Set the "encrypted" flag bit in the local header and the central directory entry.
    raw[6] |= 1
    central = raw.rfind(b"PK\x01\x02")
    raw[central + 8] |= 1
    with pytest.raises(ArchiveError, match="encrypted"):
        read_archive(bytes(raw))


def test_zip_symlink_refused() -> None:
    raw = io.BytesIO()
    with zipfile.ZipFile(raw, "w") as archive:
        info = zipfile.ZipInfo("model/link")
        info.external_attr = 0o120777 << 16
        archive.writestr(info, "/etc/passwd")
    with pytest.raises(ArchiveError, match="links are not allowed"):
        read_archive(raw.getvalue())
