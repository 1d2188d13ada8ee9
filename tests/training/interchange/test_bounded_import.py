"""The bounded import gives back what the in-process import gives: the result crosses from
the child as a file of JSON and bytes (no pickle), validated again on this side."""

from __future__ import annotations

import json

import pytest
import torch

from tests.support import tar_gz
from training.interchange.archive import import_virtual_model
from training.interchange.bounded import import_upload
from training.interchange.deepracer import ImportedDeepRacerModel
from training.interchange.export import checkpoint_bytes, load_checkpoint
from training.interchange.importwire import MAGIC, WireError, read_result, write_error

REWARD = "def reward_function(params):\n    return 1.0\n"


@pytest.fixture(scope="module")
def virtual_model(ppo_discrete) -> bytes:
    return tar_gz(
        {
            "model/model_metadata.json": ppo_discrete.metadata.dumps(),
            "ip/hyperparameters.json": json.dumps({"batch_size": 32, "lr": 0.0001}).encode(),
            "reward_function.py": REWARD.encode(),
            "model/best.zip": checkpoint_bytes(ppo_discrete.model),
            "metrics/TrainingMetrics.json": b'{"metrics": [{"reward_score": 3}]}',
        }
    )


def test_a_virtual_model_comes_back_from_the_child_as_it_is_read_here(
    virtual_model, ppo_discrete
) -> None:
    here = import_virtual_model(virtual_model)
    there = import_upload(virtual_model)
    assert not isinstance(there, ImportedDeepRacerModel)
    assert there.metadata == here.metadata
    assert there.hyperparameters == here.hyperparameters
    assert there.reward_function == here.reward_function == REWARD
    assert there.checkpoint_name == here.checkpoint_name == "best"
    assert (
        there.extra_files
        == here.extra_files
        == {"metrics/TrainingMetrics.json": b'{"metrics": [{"reward_score": 3}]}'}
    )
    model = load_checkpoint(there.checkpoint_bytes, there.metadata)
    for mine, theirs in zip(
        ppo_discrete.model.policy.parameters(), model.policy.parameters(), strict=True
    ):
        assert torch.equal(mine, theirs)


def test_a_result_that_is_not_the_childs_format_is_refused(tmp_path) -> None:
    path = tmp_path / "result"
    path.write_bytes(b"\x80\x04pickled?")
    with pytest.raises(WireError, match="no header"):
        read_result(str(path))
    path.write_bytes(MAGIC + (10**9).to_bytes(8, "big") + b"{}")
    with pytest.raises(WireError, match="header is 1,000,000,000 bytes"):
        read_result(str(path))
    header = json.dumps({"ok": True, "blobs": [["checkpoint", 5]]}).encode()
    path.write_bytes(MAGIC + len(header).to_bytes(8, "big") + header + b"abc")
    with pytest.raises(WireError, match="do not add up"):
        read_result(str(path))
    with open(path, "wb") as out:
        write_error(out, "model_metadata.json: nested too deeply to read", "archive")
    with pytest.raises(ValueError, match="^model_metadata.json: nested too deeply to read$"):
        read_result(str(path))
