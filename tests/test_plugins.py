"""Descriptor plugins: a package installed into this environment registers descriptors under the
entry-point group ``wiloc.descriptors``; ``describe --list-descriptors`` shows where each comes
from, ``describe --descriptor NAME`` computes it, and a plugin that fails to load is one warning."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest

from wiloc.cache.store import Cache

DIST, VERSION = "wiloc-test-tiny-plugin", "0.3.1"
MODULE = "wiloc_test_tiny_plugin"

PYPROJECT = f"""
[build-system]
requires = ["setuptools>=68"]
build-backend = "setuptools.build_meta"

[project]
name = "{DIST}"
version = "{VERSION}"

[project.entry-points."wiloc.descriptors"]
tiny = "{MODULE}:TINY"
broken = "{MODULE}_missing:THING"

[tool.setuptools]
py-modules = ["{MODULE}"]
"""

SOURCE = '''
"""A 4 x 4 area-resized thumbnail: the smallest descriptor a plugin can register."""
import cv2
import numpy as np
import pytest

from wiloc.descriptors import DescriptorPlugin


def tiny(gray, side=4):
    return cv2.resize(gray, (side, side), interpolation=cv2.INTER_AREA).astype(np.float32).ravel()


TINY = DescriptorPlugin(compute=tiny, metric="l1", length=16, params={"side": 4})
'''


def _wiloc(*args: str, env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "wiloc", *args], capture_output=True, text=True, env=env,
                          timeout=300, check=False)


def _pip(*args: str) -> None:
    env = {**os.environ, "PIP_NO_INDEX": "1", "PIP_DISABLE_PIP_VERSION_CHECK": "1"}
    subprocess.run([sys.executable, "-m", "pip", *args], check=True, env=env, timeout=300, capture_output=True)


def test_an_installed_plugin_is_listed_and_described(tmp_path: Path) -> None:
    package = tmp_path / "plugin"
    package.mkdir()
    (package / "pyproject.toml").write_text(PYPROJECT)
    (package / f"{MODULE}.py").write_text(SOURCE)
    route = tmp_path / "route"
    route.mkdir()
    rng = np.random.default_rng(0)
    images = [rng.integers(0, 256, (24, 32), dtype=np.uint8) for _ in range(5)]
    for i, image in enumerate(images):
        cv2.imwrite(str(route / f"f{i}.png"), image)
    env = {**os.environ, "WILOC_CACHE": str(tmp_path / "cache")}
    _pip("install", "--no-build-isolation", "--no-deps", "-q", str(package))
    try:
        listed = _wiloc("describe", "--list-descriptors", "--json", env=env)
        assert listed.returncode == 0, listed.stderr
        shown = json.loads(listed.stdout)
        rows = {row["name"]: row for row in shown["results"]}
        assert rows["tiny"] == {"name": "tiny", "source": f"{DIST} {VERSION}", "metric": "l1", "length": 16,
                                "depends": ""}
        assert rows["sad"]["source"] == "built-in" and rows["onnx"]["source"] == "built-in"
        assert "broken" not in rows
        [warning] = shown["warnings"]
        assert warning.startswith(f"warning: descriptor plugin 'broken' ({DIST} {VERSION}) failed to load: "
                                  "ModuleNotFoundError")
        table = _wiloc("describe", "--list-descriptors", env={**env, "COLUMNS": "200"})
        assert table.returncode == 0 and f"{DIST} {VERSION}" in table.stdout and "tiny" in table.stdout
        assert len(table.stderr.strip().splitlines()) == 1 and "'broken'" in table.stderr

        described = _wiloc("describe", str(route), "--descriptor", "tiny", "--json", env=env)
        assert described.returncode == 0, described.stderr
        [report] = json.loads(described.stdout)["results"]
        assert report["descriptor"] == "tiny" and report["shape"] == [5, 16] and report["computed"] == 5
        assert len(described.stderr.strip().splitlines()) == 1 and "'broken'" in described.stderr
        [info] = Cache(tmp_path / "cache").list_entries()
        assert info.params == {"side": 4, "plugin": f"{DIST} {VERSION}", "code_version": 1,  # a new release computes afresh
                               "libraries": {"opencv": cv2.__version__}}  # as does another OpenCV (it decoded the images)
        entry = Cache(tmp_path / "cache").read_entry(info.key)
        expected = [cv2.resize(image, (4, 4), interpolation=cv2.INTER_AREA).astype(np.float32).ravel()
                    for image in images]
        np.testing.assert_array_equal(entry.data, np.array(expected))
    finally:
        _pip("uninstall", "-y", "-q", DIST)
    gone = _wiloc("describe", str(route), "--descriptor", "tiny", env=env)
    assert gone.returncode == 2 and "unknown descriptor 'tiny'" in gone.stderr


def test_list_descriptors_takes_no_folder(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from wiloc.cli import app

    result = CliRunner().invoke(app, ["describe", str(tmp_path), "--list-descriptors"])
    assert result.exit_code == 2
    assert result.stderr.strip() == ("error: --list-descriptors: shows the descriptors there are; give it no FOLDER, "
                                     "--import or --list")


def _halves(gray: np.ndarray, side: int = 2) -> np.ndarray:
    return cv2.resize(gray, (side, side), interpolation=cv2.INTER_AREA).astype(np.float32).ravel()


def _installed(monkeypatch: pytest.MonkeyPatch, name: str, value: str, compute: Callable[..., np.ndarray]) -> type:
    """A plugin of 4 values per image (``compute``, metric l1) installed in process as the entry
    point ``value`` named ``name``, the registry's plugins read again; returns the entry point's class
    (the caller clears ``registry._plugins`` when done)."""
    from wiloc.descriptors import DescriptorPlugin, registry

    class Point:
        dist = None

        def load(self) -> DescriptorPlugin:
            return DescriptorPlugin(compute=compute, metric="l1", length=4, params={"side": 2})

    Point.name, Point.value = name, value
    monkeypatch.setattr(registry, "entry_points", lambda group: [Point()])
    monkeypatch.setattr(registry, "DESCRIPTORS", dict(registry.DESCRIPTORS))
    registry._plugins.cache_clear()
    return Point


def test_a_loaded_plugin_joins_the_one_registry(monkeypatch: pytest.MonkeyPatch) -> None:
    """In process: a plugin's entry point becomes a registered class like the built-in ones."""
    from wiloc.descriptors import registry

    Point = _installed(monkeypatch, "halves", "halves_module:HALVES", _halves)
    try:
        spec = registry.get_descriptor("halves")
        cls = registry.DESCRIPTORS["halves"]
        assert (cls.name, cls.source, cls.metric) == ("halves", Point.value, "l1")
        assert spec.params == {"side": 2, "plugin": Point.value}
        image = np.arange(64, dtype=np.uint8).reshape(8, 8)
        np.testing.assert_array_equal(spec.compute(image), _halves(image))
        assert [info.name for info in registry.available_descriptors()][-1] == "halves"
    finally:
        registry._plugins.cache_clear()  # the next use reads the installed plugins again


def _one_too_many(gray: np.ndarray, side: int = 2) -> np.ndarray:
    return np.zeros(side * side + 1, np.float32)


def _nan(gray: np.ndarray, side: int = 2) -> np.ndarray:
    return np.full(side * side, np.nan, np.float32)


@pytest.mark.parametrize("compute, problem", [
    (_one_too_many, "computed an array of shape (5,); it declares 4 values per image, a flat row"),
    (_nan, "computed NaN or infinite values")])
def test_a_plugin_computing_other_rows_than_it_declares_is_named(compute, problem: str, tmp_path: Path,
                                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    """A row of another length was numpy's 'could not broadcast' from inside the describing, and
    NaN rows were cached and compared: either is one error naming the plugin, from describe and
    from the localizer, and no entry is cached."""
    from wiloc import api
    from wiloc.descriptors import registry
    from wiloc.errors import WilocError
    from wiloc.localization.localizer import Localizer

    Point = _installed(monkeypatch, "odd", "odd_module:ODD", compute)
    route = tmp_path / "route"
    route.mkdir()
    for i in range(3):
        cv2.imwrite(str(route / f"f{i}.png"), np.full((24, 32), 40 * i, np.uint8))
    try:
        cache = Cache(tmp_path / "cache")
        with pytest.raises(WilocError) as err:
            api.describe(route, "odd", cache=cache, jobs=1)
        assert str(err.value) == f"descriptor 'odd' ({Point.value}): {problem}"
        assert cache.list_entries() == []
        loc = Localizer(None, descriptor="odd", method="online", cache=cache)
        with pytest.raises(WilocError) as err:
            loc.observe(np.zeros((24, 32), np.uint8))
        assert str(err.value) == f"descriptor 'odd' ({Point.value}): {problem}" and loc.frames == 0
    finally:
        registry._plugins.cache_clear()


THUMB_DIST, THUMB_MODULE = "wiloc-test-thumb-plugin", "wiloc_test_thumb_plugin"

#: A plugin that leaves a file named after the process that computed each row (in the folder
#: $WILOC_TEST_PIDS), and takes 10 ms a frame: the workers take their first batches meanwhile.
THUMB_SOURCE = '''
import os
import time
from pathlib import Path

import cv2
import numpy as np

from wiloc.descriptors import DescriptorPlugin


def thumb(gray, side=4):
    Path(os.environ["WILOC_TEST_PIDS"], str(os.getpid())).touch()
    time.sleep(0.01)
    return cv2.resize(gray, (side, side), interpolation=cv2.INTER_AREA).astype(np.float32).ravel()


THUMB = DescriptorPlugin(compute=thumb, metric="l1", length=16, params={"side": 4})
'''


def _plugin_site(site: Path, module: str, dist: str, version: str, entry: str, source: str) -> Path:
    """A plugin's module and its distribution's metadata (its entry point ``entry``) in the folder
    ``site``, as pip leaves them; returned for the module search path."""
    meta = site / f"{module}-{version}.dist-info"
    meta.mkdir(parents=True)
    (meta / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {dist}\nVersion: {version}\n")
    (meta / "entry_points.txt").write_text(f"[wiloc.descriptors]\n{entry}\n")
    (site / f"{module}.py").write_text(source)
    return site


@pytest.fixture
def thumb_plugin(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """The plugin ``thumb`` installed on the module search path (a distribution's metadata beside
    its module, as pip leaves them; worker processes search the same path), its computing
    processes' pids collected in the folder returned."""
    from wiloc.descriptors import registry

    site = _plugin_site(tmp_path / "site", THUMB_MODULE, THUMB_DIST, "1.0", f"thumb = {THUMB_MODULE}:THUMB",
                        THUMB_SOURCE)
    pids = tmp_path / "pids"
    pids.mkdir()
    monkeypatch.setenv("WILOC_TEST_PIDS", str(pids))
    monkeypatch.syspath_prepend(str(site))
    monkeypatch.setattr(registry, "DESCRIPTORS", dict(registry.DESCRIPTORS))
    monkeypatch.delitem(sys.modules, THUMB_MODULE, raising=False)
    registry._plugins.cache_clear()
    yield pids
    registry._plugins.cache_clear()  # the next use reads the installed plugins again


def test_a_plugin_spec_pickles_by_name(thumb_plugin: Path) -> None:
    """The class of a plugin is made as it loads; pickle finds it through the registry."""
    import pickle

    from wiloc.descriptors import registry

    spec = registry.get_descriptor("thumb")
    again = pickle.loads(pickle.dumps(spec))
    assert again == spec and again.kind is spec.kind is registry.DESCRIPTORS["thumb"]
    assert not hasattr(registry, "Plugin[sad]")  # a built-in class is no plugin's


#: A describe of the route (argv 1) with thumb by two workers, from the third frame on, into the
#: cache at argv 2, in a process of its own; it prints its pid, the entry's key, digest and data's hash.
WORKERS_DESCRIBE = """
import hashlib, os, sys
from wiloc import api
from wiloc.cache.store import Cache
from wiloc.description import frame_describing
from wiloc.description.frame_describing import WorkerStart
from wiloc.description.workers import can_fork
for name in ("FORKED_START", "FRESH_START"):
    setattr(frame_describing, name, WorkerStart(seconds=0.0, frames=1))
if sys.argv[3] == "fresh":
    import threading
    threading.Thread(target=threading.Event().wait, daemon=True).start()  # another thread: fresh interpreters
assert can_fork() == (sys.argv[3] == "forked")
entry = api.describe(sys.argv[1], "thumb", cache=Cache(sys.argv[2]), jobs=2)[0].entry
print(os.getpid(), entry.key, entry.digest, hashlib.sha256(entry.data.tobytes()).hexdigest())
"""


@pytest.mark.parametrize("start", ["forked", "fresh"])
def test_worker_processes_describe_a_plugin_as_this_process_does(start: str, thumb_plugin: Path,
                                                                  tmp_path: Path) -> None:
    """A plugin's class could not be pickled to the workers ('Can't pickle Plugin[tiny]'): a
    describe with workers ended in a traceback. Workers (forked, or fresh interpreters that load
    the plugin from its entry point) now compute the same cache entry as one process. The workers'
    describe runs in a process of its own: whether workers are forked depends on the threads a
    process runs, and other tests leave some running here (a Dask client's)."""
    import hashlib

    from wiloc import api

    route = tmp_path / "route"
    route.mkdir()
    rng = np.random.default_rng(1)
    for i in range(40):
        cv2.imwrite(str(route / f"f{i:02d}.png"), rng.integers(0, 256, (24, 32), dtype=np.uint8))
    alone = api.describe(route, "thumb", cache=Cache(tmp_path / "alone"), jobs=1)[0].entry
    assert {int(p.name) for p in thumb_plugin.iterdir()} == {os.getpid()}
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(tmp_path / "site"),
                                                                      os.environ.get("PYTHONPATH")]))}
    run = subprocess.run([sys.executable, "-c", WORKERS_DESCRIBE, str(route), str(tmp_path / "shared"), start],
                         capture_output=True, text=True, timeout=120, env=env, check=False)
    assert run.returncode == 0, run.stderr
    pid, key, digest, data = run.stdout.split()
    assert len({int(p.name) for p in thumb_plugin.iterdir()} - {os.getpid(), int(pid)}) == 1  # a worker computed rows
    assert (key, digest, data) == (alone.key, alone.digest, hashlib.sha256(alone.data.tobytes()).hexdigest())


#: A program that registers a descriptor of its own (its class defined in its __main__) and
#: describes the route (argv 1) into the cache at argv 2 with fresh worker processes; it prints
#: the error's parameter and problem.
MAIN_DESCRIPTOR = """
import sys, threading, time
from dataclasses import dataclass
import numpy as np
from wiloc import api
from wiloc.cache.store import Cache
from wiloc.description import frame_describing
from wiloc.description.frame_describing import WorkerStart
from wiloc.descriptors import registry
from wiloc.descriptors.base import Descriptor
from wiloc.errors import WilocError
from wiloc.parameters import Parameters

@dataclass(frozen=True)
class MeanParams(Parameters):
    owner = "mean"

class Mean(Descriptor):
    name, Params, metric = "mean", MeanParams, "l1"

    @classmethod
    def spec(cls, params):
        return cls._spec(params, dtype=np.dtype(np.float32), length=1, scale=1.0, min_size=None, natural_max=255.0)

    @classmethod
    def compute(cls, image, params):
        time.sleep(0.05)  # this process cannot describe every frame before the workers are handed theirs
        return np.array([image.mean()], np.float32)

registry.DESCRIPTORS["mean"] = Mean
for name in ("FORKED_START", "FRESH_START"):
    setattr(frame_describing, name, WorkerStart(seconds=0.0, frames=1))
threading.Thread(target=threading.Event().wait, daemon=True).start()  # another thread: fresh interpreters
try:
    api.describe(sys.argv[1], "mean", cache=Cache(sys.argv[2]), jobs=2)
except WilocError as exc:
    print(exc.parameter, exc.problem)
"""


def test_a_descriptor_registered_by_the_script_run_is_refused_by_fresh_workers_in_one_error(tmp_path: Path) -> None:
    """A fresh worker process, which never runs the caller's main script, cannot unpickle a
    descriptor class defined there: it printed pickle's traceback ("Can't get attribute 'Mean'
    on <module '__main__'>") and the describe ended in 'a worker process ended without answering'."""
    route = tmp_path / "route"
    route.mkdir()
    for i in range(40):
        cv2.imwrite(str(route / f"f{i:02d}.png"), np.full((24, 32), i, np.uint8))
    run = subprocess.run([sys.executable, "-c", MAIN_DESCRIPTOR, str(route), str(tmp_path / "cache")],
                         capture_output=True, text=True, timeout=120, check=False)
    assert run.returncode == 0 and "Traceback" not in run.stderr, run.stderr
    assert run.stdout.startswith("descriptor 'mean' cannot be described in worker processes, which do not find its "
                                 "class by name (Can't get attribute 'Mean' on <module '__main__'"), run.stdout
    assert "describe with jobs 1, or register it in a module the workers can import" in run.stdout


def _raiser(gray: np.ndarray, side: int = 2) -> np.ndarray:
    raise ValueError("cannot describe this image\n(a second line of its own)")


def test_a_plugin_whose_compute_raises_is_one_error_naming_it_and_the_frame(tmp_path: Path,
                                                                           monkeypatch: pytest.MonkeyPatch) -> None:
    """A plugin's own exception ended describe in its traceback, and came out of the localizer as
    it was: it is one error naming the descriptor, its package and the frame, and no entry is cached."""
    from wiloc import api
    from wiloc.descriptors import registry
    from wiloc.errors import WilocError
    from wiloc.localization.localizer import Localizer

    Point = _installed(monkeypatch, "raiser", "raiser_module:RAISER", _raiser)
    route = tmp_path / "route"
    route.mkdir()
    cv2.imwrite(str(route / "f0.png"), np.zeros((24, 32), np.uint8))
    try:
        cache = Cache(tmp_path / "cache")
        with pytest.raises(WilocError) as err:
            api.describe(route, "raiser", cache=cache, jobs=1)
        assert str(err.value) == f"descriptor 'raiser' ({Point.value}): failed on f0.png: ValueError: cannot describe " \
                                 "this image"
        assert err.value.__cause__ is None and cache.list_entries() == []
        loc = Localizer(None, descriptor="raiser", method="online", cache=cache)
        with pytest.raises(WilocError) as err:
            loc.observe(np.zeros((24, 32), np.uint8))
        assert str(err.value) == f"descriptor 'raiser' ({Point.value}): failed: ValueError: cannot describe this image"
    finally:
        registry._plugins.cache_clear()


RAISE_DIST, RAISE_MODULE = "wiloc-test-raise-plugin", "wiloc_test_raise_plugin"

#: A plugin taking 20 ms a frame (workers start meanwhile) that fails on the frame of value 39.
RAISE_SOURCE = '''
import time

import numpy as np

from wiloc.descriptors import DescriptorPlugin


def raiser(gray):
    time.sleep(0.02)
    if gray[0, 0] == 39:
        raise ValueError("cannot describe this image")
    return np.zeros(4, np.float32)


RAISER = DescriptorPlugin(compute=raiser, metric="l1", length=4)
'''


@pytest.mark.parametrize("jobs", ["1", "2"])
def test_describe_with_a_plugin_that_raises_ends_in_one_line(jobs: str, tmp_path: Path) -> None:
    """From the command line, in this process or a worker's: one line naming the frame, exit 1."""
    site = _plugin_site(tmp_path / "site", RAISE_MODULE, RAISE_DIST, "0.1.0", f"raiser2 = {RAISE_MODULE}:RAISER",
                        RAISE_SOURCE)
    route = tmp_path / "route"
    route.mkdir()
    for i in range(40):
        cv2.imwrite(str(route / f"f{i:02d}.png"), np.full((24, 32), i, np.uint8))
    env = {**os.environ, "WILOC_CACHE": str(tmp_path / "cache"),
           "PYTHONPATH": os.pathsep.join(filter(None, [str(site), os.environ.get("PYTHONPATH")]))}
    run = _wiloc("describe", str(route), "--descriptor", "raiser2", "-j", jobs, env=env)
    assert run.returncode == 1 and run.stderr.strip().splitlines() == [
        (f"error: descriptor 'raiser2' ({RAISE_DIST} 0.1.0): failed on f39.png: ValueError: cannot describe this "
         "image")], run.stderr


#: A local Dask cluster of one worker process, started while the plugin is on neither's module
#: search path; with argv 1 "workers", the scheduler (this process) finds it afterwards. It prints
#: the scheduler's address and runs until its stdin closes.
CLUSTER_WITHOUT_PLUGIN = """
import sys
from distributed import LocalCluster
with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster:
    if sys.argv[1] == "workers":
        sys.path.insert(0, sys.argv[2])
    print(cluster.scheduler_address, flush=True)
    sys.stdin.read()
"""


@pytest.mark.parametrize("lacking", ["scheduler", "workers"])
def test_a_cluster_without_the_plugin_is_one_error_naming_it(lacking: str, thumb_plugin: Path,
                                                             tmp_path: Path) -> None:
    """A scheduler without the plugin failed the run in two chained tracebacks (Dask's "Error
    during deserialization of the task graph"); a worker without it left the cluster, and the run
    ended 30 s later in 'no worker'. Both are one error naming the plugin, before any task is sent."""
    pytest.importorskip("distributed")
    from wiloc import api
    from wiloc.description.cluster import disconnect
    from wiloc.errors import WilocError

    route = tmp_path / "route"
    route.mkdir()
    for i in range(3):
        cv2.imwrite(str(route / f"f{i}.png"), np.full((24, 32), i, np.uint8))
    env = {key: value for key, value in os.environ.items() if key != "PYTHONPATH"}
    cluster = subprocess.Popen([sys.executable, "-c", CLUSTER_WITHOUT_PLUGIN, lacking, str(tmp_path / "site")],
                               stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env)
    try:
        address = cluster.stdout.readline().strip()
        with pytest.raises(WilocError) as err:
            api.describe(route, "thumb", cache=Cache(tmp_path / "cache"), scheduler=address)
        assert str(err.value) == (f"{address}: descriptor plugin 'thumb' is not installed on the Dask scheduler or "
                                  "its workers; install it there and restart them")
        disconnect(address)
    finally:
        cluster.stdin.close()
        try:
            cluster.wait(timeout=30)
        except subprocess.TimeoutExpired:
            cluster.kill()
            cluster.wait()
    assert not list((tmp_path / "cache").rglob("*.h5"))
