"""The order in which `make test` hands out the test files (conftest.py): the heaviest first, each file whole."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

from conftest import HEAVIEST_FIRST, pytest_collection_modifyitems


def _items(names: list[str]) -> list[SimpleNamespace]:
    return [SimpleNamespace(path=Path("tests", name), index=index) for name in names for index in range(2)]


def test_every_file_named_first_exists_once():
    """A renamed or removed file would silently drop out of the order."""
    tests = Path(__file__).parent
    assert [name for name in HEAVIEST_FIRST if not (tests / name).is_file()] == []
    assert len(set(HEAVIEST_FIRST)) == len(HEAVIEST_FIRST)


def test_a_worker_runs_the_heaviest_files_first_and_each_file_in_its_own_order():
    items = _items(["test_a.py", HEAVIEST_FIRST[1], "test_b.py", HEAVIEST_FIRST[0]])
    pytest_collection_modifyitems(SimpleNamespace(workerinput={}), items)
    expected = [HEAVIEST_FIRST[0], HEAVIEST_FIRST[1], "test_a.py", "test_b.py"]
    assert [(item.path.name, item.index) for item in items] == [(name, i) for name in expected for i in range(2)]


def test_without_workers_the_collection_order_stays():
    items = _items(["test_a.py", HEAVIEST_FIRST[0]])
    pytest_collection_modifyitems(SimpleNamespace(), items)
    assert [item.path.name for item in items] == ["test_a.py", "test_a.py", HEAVIEST_FIRST[0], HEAVIEST_FIRST[0]]
