"""Ground-truth files as people write them: cells per row, spaces and Unicode forms in names,
paths that hold a colon, folders gone, frames left out of index alignment."""
from __future__ import annotations

import unicodedata
from pathlib import Path

import numpy as np
import pytest
from helpers import ends_in_one_error, write_images
from typer.testing import CliRunner

from wiloc import api
from wiloc.cli import app
from wiloc.errors import WilocError
from wiloc.evaluation.aligned import aligned_truth
from wiloc.evaluation.groundtruth import Truth, pairs_truth, positions_truth
from wiloc.evaluation.truth_formats import exif_truth
from wiloc.evaluation.truth_source import load_truth

runner = CliRunner()
REFS = [f"img{i}.jpg" for i in range(8)]


def write(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


def pairs_of(truth: Truth) -> list[tuple[int, int]]:
    return [(int(q), int(r)) for q, r in zip(*np.nonzero(truth.matrix.toarray()))]


# --- cells per row ---------------------------------------------------------------------------

def test_a_pairs_row_of_more_cells_than_the_header_is_refused_naming_its_line(tmp_path: Path) -> None:
    csv = write(tmp_path / "p.csv", "query,reference\nimg0.jpg,img0.jpg\nimg1.jpg,img1.jpg,img2.jpg\n")
    with pytest.raises(WilocError, match=r"p\.csv: line 3: 3 cell\(s\), where the header \(line 1\) names 2 columns"):
        pairs_truth(csv, REFS, REFS)


def test_trailing_empty_cells_are_read_past(tmp_path: Path) -> None:
    """A comma at each row's end (as spreadsheets export) adds an empty cell, which names nothing."""
    csv = write(tmp_path / "p.csv", "query,reference\nimg0.jpg,img0.jpg,\nimg1.jpg,img2.jpg,,\n")
    truth = pairs_truth(csv, REFS, REFS)
    assert pairs_of(truth) == [(0, 0), (1, 2)] and truth.warnings == []


def test_a_positions_row_of_more_cells_than_the_header_is_refused(tmp_path: Path) -> None:
    csv = write(tmp_path / "q.csv", "name,x,y\nimg0.jpg,0,0\nimg1.jpg,1,0,5\n")
    with pytest.raises(WilocError, match=r"line 3: 4 cell\(s\)"):
        positions_truth(csv, csv, 1.0, REFS[:2], REFS[:2])


def test_a_pairs_row_that_lost_its_reference_cell_is_refused_naming_its_line(tmp_path: Path) -> None:
    for text in ("query,reference\nimg5.jpg\nimg6.jpg,img6.jpg\n", "query,reference\nimg5.jpg,\nimg6.jpg,img6.jpg\n"):
        csv = write(tmp_path / "p.csv", text)
        with pytest.raises(WilocError, match=r"p\.csv: line 2: "):
            pairs_truth(csv, REFS, REFS)


def test_a_negative_tolerance_names_its_line(tmp_path: Path) -> None:
    csv = write(tmp_path / "p.csv", "query,reference,tolerance\nimg5.jpg,img5.jpg,2\nimg6.jpg,img6.jpg,-1\n")
    with pytest.raises(WilocError, match=r"tolerance must be a whole number of frames >= 0 \(first: line 3\)"):
        pairs_truth(csv, REFS, REFS)


def test_a_header_only_positions_file_says_so(tmp_path: Path) -> None:
    csv = write(tmp_path / "q.csv", "name,x,y\n")
    with pytest.raises(WilocError, match="holds no positions, only its header line"):
        positions_truth(csv, csv, 1.0, REFS, REFS)


# --- names as written ------------------------------------------------------------------------

def test_a_quoted_name_keeps_its_spaces(tmp_path: Path) -> None:
    """A frame whose real name starts with a space matches its quoted row; spaces after a comma
    that are not quoted are read past, as before."""
    names = ["img0.jpg", " img1.jpg"]
    csv = write(tmp_path / "p.csv", 'query,reference\n" img1.jpg",img0.jpg\nimg0.jpg, img0.jpg\n')
    assert pairs_of(pairs_truth(csv, names, names)) == [(0, 0), (1, 0)]
    pos = write(tmp_path / "q.csv", 'name,x,y\n" img1.jpg",0,0\nimg0.jpg, 9, 0\n')
    assert pairs_of(positions_truth(pos, pos, 1.0, names, names)) == [(0, 0), (1, 1)]


def test_names_in_nfc_and_nfd_match(tmp_path: Path) -> None:
    """Frames copied from macOS (NFD) match names typed on Linux (NFC), and the other way round."""
    nfc = [unicodedata.normalize("NFC", f"café{i}.jpg") for i in range(3)]
    nfd = [unicodedata.normalize("NFD", name) for name in nfc]
    assert pairs_of(aligned_truth(nfc, nfd, 0)) == [(0, 0), (1, 1), (2, 2)]
    csv = write(tmp_path / "p.csv", "query,reference\n" + "".join(f"{n},{n}\n" for n in nfd))
    assert pairs_of(pairs_truth(csv, nfc, nfd)) == [(0, 0), (1, 1), (2, 2)]
    pos = write(tmp_path / "q.csv", "name,x,y\n" + "".join(f"{n},{i * 10},0\n" for i, n in enumerate(nfc)))
    assert pairs_of(positions_truth(pos, pos, 1.0, nfd, nfd)) == [(0, 0), (1, 1), (2, 2)]


# --- folders and --gt ------------------------------------------------------------------------

def test_exif_truth_of_a_folder_gone_says_it_does_not_exist(tmp_path: Path) -> None:
    with pytest.raises(WilocError, match=r"q_moved: folder does not exist"):
        exif_truth(tmp_path / "q_moved", None, 25.0, REFS, REFS)


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A threshold run of 6 frames against the same 6 frames, named img0 .. img5."""
    root = tmp_path_factory.mktemp("gt-run")
    write_images(root / "q", 6)
    write_images(root / "map", 6)
    out = root / "run.csv"
    result = runner.invoke(app, ["localize", str(root / "q"), "--map", str(root / "map"), "--method", "threshold",
                                 "--out", str(out), "--jobs", "1", "--cache", str(root / "cache")])
    assert result.exit_code == 0, result.output
    return out


def test_gt_file_whose_path_holds_a_colon_is_read_as_the_file(run: Path, tmp_path: Path) -> None:
    folder = tmp_path / "2024-05-01T10:00"
    folder.mkdir()
    names = [f"img{i}.{'png' if i % 2 else 'jpg'}" for i in range(6)]
    write(folder / "gt.csv", "query,reference\n" + "".join(f"{n},{n}\n" for n in names))
    for gt in (str(folder / "gt.csv"), f"pairs:{folder / 'gt.csv'}"):
        result = runner.invoke(app, ["evaluate", str(run), "--gt", gt, "--json"])
        assert result.exit_code == 0, result.output
        assert '"with_true_match": 6' in result.stdout
    result = runner.invoke(app, ["evaluate", str(run), "--gt", str(tmp_path / "2024-05-01T11:00/gt.csv")])
    ends_in_one_error(result, 2, "neither a ground-truth form nor a file")


# --- aligned by index: frames left out -------------------------------------------------------

def test_aligned_by_index_warns_of_a_frame_left_out_of_the_map(tmp_path: Path) -> None:
    """A map image the run left out (unreadable) shifts every later map frame's position."""
    names = write_images(tmp_path / "map", 6)
    queries = [f"frame{i}.png" for i in range(6)]
    kept = names[:2] + names[3:]
    (tmp_path / "map" / names[2]).write_bytes(b"not an image")  # why the run left it out
    truth = load_truth("aligned", None, query_names=queries, ref_names=kept, by="index",
                       query_folder=tmp_path / "q", ref_folder=tmp_path / "map")
    line = next(w for w in truth.warnings if "img2.jpg" in w)
    assert "left out of the run" in line and "shifted" in line, truth.warnings
    truth = load_truth("aligned", None, query_names=queries, ref_names=names, by="index",
                       query_folder=tmp_path / "q", ref_folder=tmp_path / "map")
    assert truth.warnings == []
    truth = load_truth("aligned", None, query_names=kept, ref_names=kept, by="index", query_folder=tmp_path / "map")
    assert truth.warnings == []  # a traversal against itself: both sides are shifted alike


def test_aligned_by_index_warns_of_a_bag_whose_names_are_stamps(tmp_path: Path) -> None:
    """A bag's frames are named by their stamps, so a sampled bag's positions are not its indices."""
    bag = write(tmp_path / "left.bag", "not read")
    stamps = [f"t1700000000.{i * 500_000_000:09d}" for i in range(2)] + ["t1700000001.000000000"]
    truth = load_truth("aligned", None, query_names=stamps, ref_names=REFS, by="index",
                       query_folder=bag, ref_folder=tmp_path / "map")
    assert any("left.bag" in w and "--every" in w for w in truth.warnings), truth.warnings


# --- aligned: a map frame left out -----------------------------------------------------------

def test_a_map_frame_left_out_shifts_no_aligned_band(tmp_path: Path) -> None:
    """A run against a map with one image cut short (left out, as it should be): its results
    header records where that frame was, and aligned +-2 counts the map's full order, so the
    truth is every frame's neighbours within +-2 by name, the one left out dropped. Before, the
    band counted the kept frames: query img3 was true against img6, and img4 had no true match."""
    queries = write_images(tmp_path / "q", 10)
    write_images(tmp_path / "map", 10, seed=1)
    cut = tmp_path / "map" / "img4.jpg"
    cut.write_bytes(cut.read_bytes()[:len(cut.read_bytes()) // 2])
    out = tmp_path / "run.csv"
    result = runner.invoke(app, ["localize", str(tmp_path / "q"), "--map", str(tmp_path / "map"), "--method",
                                 "threshold", "--out", str(out), "--jobs", "1", "--cache", str(tmp_path / "cache")])
    assert result.exit_code == 0, result.output
    assert '# reference_left_out: [[4, "img4.jpg"]]\n' in out.read_text(encoding="utf-8")
    truth = api.evaluate(out, api.TruthSource(kind="aligned", tolerance=2)).truth
    kept = [name for name in queries if name != "img4.jpg"]
    by_name = np.array([[abs(i - int(ref[3:-4])) <= 2 for ref in kept] for i in range(10)])
    assert truth.ref_names == kept
    np.testing.assert_array_equal(truth.matrix.toarray(), by_name)
    result = runner.invoke(app, ["evaluate", str(out), "--gt", "aligned", "-T", "2", "--json"])
    assert result.exit_code == 0, result.output
    assert '"with_true_match": 10' in result.stdout
