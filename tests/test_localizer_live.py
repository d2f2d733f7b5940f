"""A Localizer in live use: Ctrl-C during a frame, options it does not use, images it refuses, and
what it says of itself and keeps when saved."""
from __future__ import annotations

import copy
import os
import pickle
import signal
import threading
from pathlib import Path

import cv2
import numpy as np
import pytest

from wiloc import demo
from wiloc.errors import ParameterError, WilocError
from wiloc.localization.localizer import Localizer


def _key(loc: Localizer, frame: Path) -> str:
    d = loc.observe(frame)
    return repr((d.match, d.difference, d.confidence, d.new_place, d.ranking))


def test_ctrl_c_during_a_step_completes_the_frame_then_interrupts(demo_route: demo.DemoRoute, cache_dir: Path,
                                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    """Ctrl-C inside the method's step (catgraph's several arrays) left the filter advanced and
    the frame uncounted: a state saved then, continued, decided otherwise. The frame is now
    completed and counted, the interrupt raised after it, and the run goes on as an
    uninterrupted one."""
    frames = sorted(demo_route.queries[0].iterdir())[:40]
    uninterrupted = Localizer(demo_route.reference, method="catgraph", seed=0)
    expected = [_key(uninterrupted, f) for f in frames]
    loc = Localizer(demo_route.reference, method="catgraph", seed=0)
    got = [_key(loc, f) for f in frames[:20]]
    step = loc.method.step

    def step_then_ctrl_c(row: np.ndarray, odometry: float | None) -> object:
        decision = step(row, odometry)
        os.kill(os.getpid(), signal.SIGINT)
        return decision

    monkeypatch.setattr(loc.method, "step", step_then_ctrl_c)
    with pytest.raises(KeyboardInterrupt):
        loc.observe(frames[20])
    monkeypatch.undo()
    assert loc.frames == 21 and loc.names[-1] == frames[20].name
    resumed = Localizer.load(loc.save(cache_dir.parent / "state.npz"))
    assert got + [_key(resumed, f) for f in frames[21:]] == expected[:20] + expected[21:]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_interrupts_are_deferred_in_the_main_thread_only() -> None:
    """Elsewhere no handler can be set: the block runs as it is."""
    from wiloc.interrupts import interrupts_deferred

    ran = []

    def block() -> None:
        with interrupts_deferred():
            ran.append(threading.current_thread().name)

    thread = threading.Thread(target=block)
    thread.start()
    thread.join()
    with pytest.raises(KeyboardInterrupt), interrupts_deferred():
        os.kill(os.getpid(), signal.SIGINT)
        ran.append("main, whole")
    assert len(ran) == 2 and ran[1] == "main, whole"


def _matrix_map(tmp_path: Path) -> Path:
    np.save(tmp_path / "map.npy", np.random.default_rng(7).random((40, 32)).astype(np.float32))
    return tmp_path / "map.npy"


def test_options_the_map_does_not_use_are_refused(demo_route: demo.DemoRoute, tmp_path: Path,
                                                  cache_dir: Path) -> None:
    """An unknown metric, a metric, names file or map odometry that the map (or sequence mode)
    would not use were accepted and ignored, a missing file's path even saved in the state."""
    from wiloc.description.traversals import entry_from_array
    from wiloc.descriptors.registry import get_descriptor

    rows = np.random.default_rng(0).random((30, 8)).astype(np.float32)
    in_memory = entry_from_array(rows, [f"m{i}" for i in range(30)], get_descriptor("external", metric="l1", length=8))
    for given, parameter, said in (
            ({"map": None, "metric": "l7"}, "metric", "applies to a map that is a descriptor matrix file"),
            ({"map": in_memory, "metric": "l7"}, "metric", "the map held in memory is compared by 'l1', not 'l7'"),
            ({"map": None, "metric": "l1"}, "metric", "applies to a map that is a descriptor matrix file"),
            ({"map": in_memory, "metric": "cosine"}, "metric", "the map held in memory is compared by 'l1'"),
            ({"map": None, "map_odometry": tmp_path / "no.csv"}, "map_odometry", "applies against a map"),
            ({"map": demo_route.reference, "map_names": tmp_path / "no.txt"}, "map_names",
             "applies to a map that is a descriptor matrix file")):
        with pytest.raises(ParameterError, match=said) as err:
            Localizer(method="catgraph", **given)
        assert err.value.parameter == parameter
    assert Localizer(in_memory, metric="l1", method="online").metric == "l1"


def test_a_float_image_just_outside_0_1_says_so_without_the_8_bit_hint(demo_route: demo.DemoRoute,
                                                                        cache_dir: Path) -> None:
    """One pixel at 1.0000001 read as [0.0156863, 1], told to be an 8-bit image's values."""
    loc = Localizer(demo_route.reference, method="threshold")
    image = cv2.imread(str(sorted(demo_route.queries[0].iterdir())[10]), cv2.IMREAD_GRAYSCALE) / 255.0
    image[0, 0] = 1.0000001
    with pytest.raises(WilocError) as err:
        loc.observe(image)
    assert "1.0000001] found)" in str(err.value) and "8-bit" not in str(err.value)
    image[0, 0] = 1.02
    with pytest.raises(WilocError) as err:
        loc.observe(image)
    assert "1.02] found)" in str(err.value) and "8-bit" not in str(err.value)
    assert loc.frames == 0


def test_a_matrix_map_names_its_descriptor_as_its_results_do(tmp_path: Path, cache_dir: Path) -> None:
    """repr said descriptor='sad' where the results header says external:l1."""
    loc = Localizer(_matrix_map(tmp_path), metric="l1", method="catgraph")
    assert loc.header().descriptor == "external:l1" and "descriptor='external:l1'" in repr(loc)
    assert "descriptor='sad'" in repr(Localizer(None, method="online"))


def test_the_doubts_about_frames_are_kept_by_save_pickle_and_copy(demo_route: demo.DemoRoute, tmp_path: Path,
                                                                  cache_dir: Path) -> None:
    """A restored localizer had lost them (and the shapes seen), and warned again."""
    loc = Localizer(demo_route.reference, method="threshold")
    image = cv2.imread(str(sorted(demo_route.queries[0].iterdir())[10]), cv2.IMREAD_GRAYSCALE)
    loc.observe(image)
    loc.observe(image[:, :40])
    assert len(loc.frame_doubts) == 1
    for other in (Localizer.load(loc.save(tmp_path / "state.npz")), pickle.loads(pickle.dumps(loc)),
                  copy.deepcopy(loc)):
        assert other.frame_doubts == loc.frame_doubts
        other.observe(image[:, :40])
        assert other.frame_doubts == loc.frame_doubts
