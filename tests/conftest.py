"""Shared fixtures: where the real datasets are, a cache shared by the real-data tests, the demo route."""
from __future__ import annotations

import os
import signal
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

if TYPE_CHECKING:
    from wiloc import demo

REPO = Path(__file__).resolve().parents[1]


def _data_root() -> Path | None:
    env = os.environ.get("WILOC_DATA")
    root = Path(env) if env else REPO.parent / "shared" / "data"
    return root if root.is_dir() else None


def pytest_configure(config: pytest.Config) -> None:
    """Ctrl-C reaches the processes the tests start. A suite started in the background by a
    non-interactive shell inherits SIGINT ignored, and so would every process it starts (wiloc,
    as Python, keeps an ignored SIGINT ignored): the tests that interrupt a run would see it
    finish. A handler of this process's own is reset to the default in each child."""
    if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if _data_root() is not None:
        return
    skip = pytest.mark.skip(reason="real datasets not found: set WILOC_DATA")
    for item in items:
        if "realdata" in item.keywords:
            item.add_marker(skip)


@pytest.fixture(scope="session")
def data_root() -> Path:
    """The folder holding gardens-point-walking/ and nordland-summer-winter-64x32/."""
    root = _data_root()
    if root is None:
        pytest.skip("real datasets not found: set WILOC_DATA")
    return root


@pytest.fixture(scope="session")
def demo_route(tmp_path_factory: pytest.TempPathFactory) -> demo.DemoRoute:
    """wiloc's demo route (seconds to draw and write), made once a session: tests only read it."""
    from wiloc import demo

    return demo.make_demo_route(tmp_path_factory.mktemp("demo-route"))


@pytest.fixture(scope="session")
def real_data_cache(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A cache folder shared by the real-data tests that compute the same things and check what
    a run decides, not what it computes or reuses: each dataset folder's descriptors (Gardens
    Point's gist alone takes seconds a walk), their difference matrices and the vocabularies are
    made once a session, by whichever test needs them first. The example scripts share it too
    (table1.py and loop_closure.py train the same Gardens Point vocabularies, minutes of SIFT
    features and k-means; test_fabmap_method.py's day_left run uses table1.py's night_right one)."""
    return tmp_path_factory.mktemp("real-data") / "cache"


@pytest.fixture
def cache_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A private cache folder, also set as WILOC_CACHE so subprocesses use it."""
    path = tmp_path / "cache"
    monkeypatch.setenv("WILOC_CACHE", str(path))
    return path
