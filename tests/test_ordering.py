"""The suite's file order (tests/ordering.py): the longest files first, each file whole."""

from __future__ import annotations

import json
from dataclasses import dataclass, field

from tests import ordering


@dataclass
class Item:
    nodeid: str
    marks: set[str] = field(default_factory=set)

    def get_closest_marker(self, name: str) -> object | None:
        return name if name in self.marks else None


def ids(items: list[Item]) -> list[str]:
    return [i.nodeid for i in items]


def test_recorded_files_go_longest_first_and_stay_whole() -> None:
    items = [
        Item("tests/a.py::one"),
        Item("tests/b.py::one"),
        Item("tests/a.py::two"),
        Item("tests/c.py::one"),
    ]
    order = ordering.file_order(items, {"tests/a.py": 1.0, "tests/b.py": 30.0, "tests/c.py": 5.0})
    assert ids(order) == [
        "tests/b.py::one",
        "tests/c.py::one",
        "tests/a.py::one",
        "tests/a.py::two",
    ]


def test_an_unrecorded_file_is_ranked_by_its_marks_and_ties_by_path() -> None:
    items = [
        Item("tests/quick.py::" + str(n))
        for n in range(20)  # 20 quick tests: 4 s
    ] + [
        Item("tests/z_browser.py::one", {"browser", "slow"}),
        Item("tests/slow.py::one", {"slow"}),
        Item("tests/y_browser.py::one", {"browser", "slow"}),
    ]
    order = ordering.file_order(items, {})
    files = list(dict.fromkeys(i.nodeid.split("::")[0] for i in order))
    assert files == ["tests/y_browser.py", "tests/z_browser.py", "tests/slow.py", "tests/quick.py"]


def test_the_checked_in_record_reads_whole() -> None:
    recorded = json.loads(ordering.DURATIONS.read_text())
    assert recorded, "tests/durations.json is empty"
    assert ordering._recorded() == recorded
    assert all(path.startswith("tests/") and seconds >= 0 for path, seconds in recorded.items())


def test_a_missing_or_broken_record_orders_by_marks(tmp_path, monkeypatch) -> None:
    monkeypatch.setattr(ordering, "DURATIONS", tmp_path / "durations.json")
    assert ordering._recorded() == {}
    (tmp_path / "durations.json").write_text("[1, 2")
    assert ordering._recorded() == {}
