"""Model-import bombs (issue 22, item 7): uploads that declare far more than a DeepRacer model
are refused before anything is built, an import runs in a bounded child process whose memory
goes back to the system, and every failure says its reason."""

from __future__ import annotations

import gc
import io
import os
import signal
import tarfile
import tracemalloc

import numpy as np
import psutil
import pytest
from tensorboard.compat.proto import attr_value_pb2
from tensorboard.compat.proto.tensor_shape_pb2 import TensorShapeProto
from tensorboard.util import tensor_util

from tests.training.interchange.bomb_support import (
    car_archive_files,
    fill,
    identity_chain,
    matmul_chain,
    ones,
    op,
    tar_gz,
    with_nodes,
)
from training.interchange import bounded
from training.interchange.archive import ArchiveError
from training.interchange.bounded import ImportBounds, ImportStopped, import_upload
from training.interchange.deepracer import import_car_archive
from training.interchange.graphbudget import GraphBudgetError, check_graph
from training.interchange.tfgraph import GraphError, parse_graph, run_graph

MB = 1024 * 1024
SMALL_GROWTH = 40 * MB
"""What the test process may grow by around a refused bomb (a built 50 M fill is 200 MB)."""
BOMB_MESSAGE = (
    "agent/model.pb: the constant 'x' declares 50,000,000 values; a DeepRacer model has at "
    "most 40,000,000 in one tensor"
)


@pytest.fixture(scope="module")
def car_files() -> dict[str, bytes]:
    return car_archive_files()


def rss() -> int:
    gc.collect()
    return psutil.Process().memory_info().rss


def peak_of(call) -> tuple[Exception | None, int]:
    """What ``call`` raised and the most memory (Python and numpy) it held at once."""
    tracemalloc.start()
    try:
        call()
        raised = None
    except Exception as exc:
        raised = exc
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return raised, peak


def test_a_fill_declaring_50_million_values_is_refused_before_it_is_built(car_files) -> None:
    bomb = with_nodes(car_files, fill("x", [50_000_000]))
    assert len(bomb) < 2 * MB  # a small upload...
    with pytest.raises(ArchiveError) as first:
        import_car_archive(bomb)  # warm-up: every module is loaded
    assert str(first.value).startswith(BOMB_MESSAGE)
    before = rss()
    raised, peak = peak_of(lambda: import_car_archive(bomb))
    assert isinstance(raised, ArchiveError) and str(raised).startswith(BOMB_MESSAGE)
    assert peak < SMALL_GROWTH, f"{peak / MB:.0f} MB held while refusing the bomb"
    assert rss() - before < SMALL_GROWTH


def test_the_bomb_through_the_bounded_child_leaves_the_caller_unchanged(car_files) -> None:
    bomb = with_nodes(car_files, fill("x", [50_000_000]), fill("y", [50_000_000]))
    before = rss()
    for _ in range(2):  # the report: 5.6 GB after one upload, 8.4 GB after two
        with pytest.raises(ArchiveError) as refused:
            import_upload(bomb)
        assert str(refused.value).startswith(BOMB_MESSAGE)
    growth = rss() - before
    print(f"test process RSS: {before / MB:.0f} MB before, grew {growth / MB:.1f} MB")
    assert growth < SMALL_GROWTH


def test_fills_under_the_tensor_bound_are_refused_by_their_total(car_files) -> None:
    bomb = with_nodes(car_files, *(fill(f"f{i}", [30_000_000]) for i in range(3)))
    raised, peak = peak_of(lambda: import_car_archive(bomb))
    assert isinstance(raised, ArchiveError)
    assert str(raised).startswith("agent/model.pb: the graph's constants declare 90,")
    assert str(raised).endswith("values in all; a DeepRacer model has at most 64,000,000")
    assert peak < SMALL_GROWTH


def test_a_matmul_chain_is_refused_by_the_compute_check_before_it_runs() -> None:
    graph = matmul_chain(size=3000, length=40, start="A")  # 27 G multiply-adds a link
    raised, peak = peak_of(lambda: check_graph(graph))
    assert isinstance(raised, GraphBudgetError)
    assert "multiply-adds per image (at 'mm0', 27,000,000,000)" in str(raised)
    assert peak < SMALL_GROWTH  # the 36 MB matrix was never built
    with pytest.raises(GraphError, match="multiply-adds"):
        run_graph(graph, {"x": ones((1, 3000))}, "mm39")


def test_a_chain_the_check_cannot_see_is_stopped_while_it_runs() -> None:
    """With an input of unknown shape the multiply-adds are counted on the real operands,
    before each op: 1.5 G per fed image, reached after about 166 links of 9 M."""
    graph = matmul_chain(size=3000, length=400)
    graph.node[0].attr["shape"].CopyFrom(
        attr_value_pb2.AttrValue(shape=TensorShapeProto(unknown_rank=True))
    )
    assert check_graph(graph).macs_per_image == 0  # nothing to count beforehand
    with pytest.raises(GraphError) as stopped:
        run_graph(graph, {"x": ones((1, 3000))}, "mm399")
    assert str(stopped.value).startswith("mm166: the graph needs more than 1,500,000,000")


def test_a_broadcast_that_would_make_a_huge_tensor_is_refused() -> None:
    graph = matmul_chain(size=2, length=0)
    graph.node.extend([fill("col", [10_000, 1]), fill("row", [1, 10_000])])
    graph.node.append(op("Add", "square", "col", "row"))
    with pytest.raises(GraphBudgetError, match="square: the op Add would make 100,000,000"):
        check_graph(graph)


def test_a_deep_graph_is_refused_and_a_long_one_runs_without_recursion() -> None:
    with pytest.raises(GraphBudgetError, match="more than 1,200 nodes deep .at 'id1199'."):
        check_graph(identity_chain(1_500))
    long = identity_chain(1_100)  # deeper than Python's recursion limit
    out = run_graph(long, {"x": ones((2, 4))}, "id1099")
    np.testing.assert_array_equal(out, ones((2, 4)))


def test_a_graph_of_too_many_nodes_is_refused() -> None:
    graph = matmul_chain(size=2, length=0)
    graph.node.extend(fill(f"c{i}", [1]) for i in range(2_500))
    with pytest.raises(GraphBudgetError, match="the graph has 2,502 nodes; .* at most 2,000"):
        check_graph(graph)


def test_bad_attributes_say_what_is_wrong() -> None:
    graph = matmul_chain(size=2, length=0)
    graph.node.append(fill("k", [2, 2, 1, 1]))
    graph.node.append(op("Conv2D", "conv", "x", "k", strides=[1, 0, 0, 1]))
    with pytest.raises(GraphBudgetError, match=r"conv: strides must be 4 positive numbers"):
        check_graph(graph)


def test_a_graph_of_bad_values_gives_its_reason(car_files) -> None:
    """A Reshape to a shape its input cannot take: refused, naming the node, never a crash."""
    graph = parse_graph(car_files["agent/model.pb"])
    target = next(n for n in graph.node if n.op == "Const" and n.name.endswith("/shape"))
    target.attr["value"].tensor.CopyFrom(tensor_util.make_tensor_proto(np.int32([-1, 7])))
    bad = tar_gz({**car_files, "agent/model.pb": graph.SerializeToString()})
    with pytest.raises(ArchiveError, match=r"^agent/model\.pb: .*cannot reshape"):
        import_upload(bad)


def test_an_op_missing_an_operand_gives_its_reason(car_files) -> None:
    """Once an uncaught IndexError: "The task could not finish; try again." """
    graph = parse_graph(car_files["agent/model.pb"])
    matmul = next(n for n in graph.node if n.op == "MatMul")
    del matmul.input[1:]
    bad = tar_gz({**car_files, "agent/model.pb": graph.SerializeToString()})
    with pytest.raises(ArchiveError) as refused:
        import_car_archive(bad)
    assert str(refused.value) == (
        "agent/model.pb: the graph does not fit a Racecraft network "
        "(IndexError: list index out of range)"
    )


def test_deeply_nested_metadata_gives_its_reason_from_the_child(car_files) -> None:
    nested = tar_gz({**car_files, "model_metadata.json": b"[" * 200_000})
    with pytest.raises(ArchiveError) as refused:
        import_upload(nested)
    assert not isinstance(refused.value, ImportStopped)
    assert str(refused.value) == "model_metadata.json: nested too deeply to read"


def test_a_child_past_its_memory_limit_is_stopped_and_the_caller_is_unchanged(car_files):
    """200 MB of zeros in the archive (200 KB compressed) against a 64 MB budget."""
    raw = io.BytesIO()
    with tarfile.open(fileobj=raw, mode="w:gz", compresslevel=1) as tar:
        for name, data in car_files.items():
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
        info = tarfile.TarInfo("zeros.txt")
        info.size = 200 * MB
        tar.addfile(info, io.BytesIO(bytes(200 * MB)))
    upload = raw.getvalue()
    before = rss()
    with pytest.raises(ImportStopped) as stopped:
        import_upload(upload, ImportBounds(memory_bytes=64 * MB))
    assert str(stopped.value) == "the import used more than 64 MB of memory and was stopped"
    assert rss() - before < SMALL_GROWTH
    # within the default budget the same upload imports: the limit is what stopped it
    imported = import_upload(upload)
    assert imported.metadata.neural_network == "RACECRAFT_LEAN_CNN"


def test_a_child_past_its_deadline_is_killed(monkeypatch, tmp_path) -> None:
    """A child that never answers (a stand-in module that sleeps) is killed at the deadline."""
    pid_file = tmp_path / "pid"
    monkeypatch.setattr(bounded, "CHILD_MODULE", "tests.training.interchange.stalled_child")
    monkeypatch.setattr(bounded, "_child_env", lambda folder: {"STALL_PID_FILE": str(pid_file)})
    with pytest.raises(ImportStopped, match=r"^the import took longer than 2 s and was stopped$"):
        import_upload(b"x", ImportBounds(wall_seconds=2))
    pid = int(pid_file.read_text())
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)  # gone, and reaped


def test_a_child_past_its_cpu_time_is_stopped(monkeypatch) -> None:
    monkeypatch.setattr(bounded, "CHILD_MODULE", "tests.training.interchange.spinning_child")
    with pytest.raises(ImportStopped, match=r"^the import used more than 1 s of CPU time"):
        import_upload(b"x", ImportBounds(cpu_seconds=1, wall_seconds=120))


def test_a_child_that_dies_says_so() -> None:
    error = bounded._outcome(bounded.PROJECT_ROOT, -signal.SIGSEGV, 0.0, ImportBounds())
    assert str(error) == "the import stopped unexpectedly (signal SIGSEGV)"
