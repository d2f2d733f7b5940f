"""`wiloc describe --import ... --out FILE.h5`: hloc's global-feats-*.h5 and folders of per-image
.npy vectors become wiloc descriptor files that record names and metric, so that localize takes
them without --names and --metric; bad sources are one line and a non-zero exit code."""
from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import pytest
from helpers import ends_in_one_error, write_images
from typer.testing import CliRunner

from wiloc import api
from wiloc.cli import app
from wiloc.description.traversals import descriptor_label
from wiloc.descriptors.external import read_external, recorded_metric
from wiloc.errors import WilocError
from wiloc.evaluation.results import read_results

runner = CliRunner()
N, D = 12, 32


def _descriptors(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Map descriptors and query descriptors of the same places (a little noise apart)."""
    rng = np.random.default_rng(seed)
    ref = rng.normal(size=(N, D)).astype(np.float32)
    return ref, ref + rng.normal(scale=0.05, size=ref.shape).astype(np.float32)


def _hloc_file(path: Path, groups: dict[str, np.ndarray]) -> Path:
    """A global-feats file as hloc's extract_features writes it: one group per image name (a name
    with '/' is nested groups), dataset global_descriptor in float16 (hloc's as_half)."""
    with h5py.File(path, "w") as handle:
        for name, vector in groups.items():
            group = handle.create_group(name)
            group.create_dataset("global_descriptor", data=vector.astype(np.float16))
            group.create_dataset("image_size", data=np.array([640, 480]))
    return path


def _invoke(*args: str | Path) -> None:
    result = runner.invoke(app, [str(a) for a in args])
    assert result.exit_code == 0, result.output


def _localized(query: Path, ref: Path, out: Path) -> list[tuple[str, str]]:
    """Each query frame and its match, from a localize run given the two files alone."""
    _invoke("localize", query, "--map", ref, "--method", "threshold", "--out", out)
    results = read_results(out)
    assert results.header.metric == "cosine"
    return list(zip(results.frames["frame"], results.frames["match"]))


def test_an_hloc_file_imports_in_two_parts_and_localizes(tmp_path: Path, cache_dir: Path) -> None:
    ref, query = _descriptors()
    feats = _hloc_file(tmp_path / "global-feats-netvlad.h5",
                       {**{f"db/img{i}.jpg": v for i, v in enumerate(ref)},
                        **{f"query/night/img{i}.jpg": v for i, v in enumerate(query)}})
    _invoke("describe", "--import", feats, "--prefix", "db/", "--metric", "cosine", "--out", tmp_path / "map.h5")
    _invoke("describe", "--import", feats, "--prefix", "query/", "--metric", "cosine", "--out", tmp_path / "query.h5")
    assert recorded_metric(tmp_path / "map.h5") == "cosine"
    pairs = _localized(tmp_path / "query.h5", tmp_path / "map.h5", tmp_path / "run.csv")
    assert pairs == [(f"night/img{i}.jpg", f"img{i}.jpg") for i in range(N)]  # natural order, names with '/'


def test_a_folder_of_npy_files_imports_and_localizes(tmp_path: Path, cache_dir: Path) -> None:
    ref, query = _descriptors(1)
    for folder, rows in (("database", ref), ("queries", query)):
        for i, vector in enumerate(rows):
            path = tmp_path / folder / f"part{i % 2}" / f"img{i}.jpg.npy"
            path.parent.mkdir(parents=True, exist_ok=True)
            np.save(path, vector)
        _invoke("describe", "--import", tmp_path / folder, "--metric", "cosine", "--out", tmp_path / f"{folder}.h5")
    pairs = _localized(tmp_path / "queries.h5", tmp_path / "database.h5", tmp_path / "run.csv")
    assert sorted(pairs) == sorted((f"part{i % 2}/img{i}.jpg",) * 2 for i in range(N))
    names, matrix = read_external(tmp_path / "queries.h5", None, "cosine")
    assert np.array_equal(matrix[names.index("part1/img3.jpg")], query[3])


def test_the_recorded_metric_names_the_results_and_an_explicit_one_wins(tmp_path: Path, cache_dir: Path) -> None:
    ref, _ = _descriptors()
    feats = _hloc_file(tmp_path / "feats.h5", {f"img{i}.jpg": v for i, v in enumerate(ref)})
    _invoke("describe", "--import", feats, "--metric", "sqeuclidean", "--out", tmp_path / "seq.h5")
    result = runner.invoke(app, ["localize", str(tmp_path / "seq.h5"), "--method", "threshold", "-R", "1"])
    assert result.exit_code == 0, result.output
    header = read_results(Path("seq-external-sqeuclidean-threshold.csv")).header
    assert (header.metric, header.descriptor) == ("sqeuclidean", "external:sqeuclidean")  # its name's label
    _invoke("localize", tmp_path / "seq.h5", "--metric", "l1", "--method", "threshold", "-R", "1", "--out", tmp_path / "l1.csv")
    assert read_results(tmp_path / "l1.csv").header.metric == "l1"


def test_one_label_names_imported_descriptors(tmp_path: Path) -> None:
    """Results files and their headers take the descriptor's label from one place: a matrix file
    (its recorded metric, or the one given), rows given as ``external``, a described folder."""
    ref, _ = _descriptors()
    feats = _hloc_file(tmp_path / "feats.h5", {f"img{i}.jpg": v for i, v in enumerate(ref)})
    _invoke("describe", "--import", feats, "--metric", "cosine", "--out", tmp_path / "cos.h5")
    folder = tmp_path / "frames"
    write_images(folder, 2)
    assert descriptor_label("sad", None, [folder, tmp_path / "cos.h5"]) == "external:cosine"
    assert descriptor_label("sad", "l1", [tmp_path / "cos.h5"]) == "external:l1"
    assert descriptor_label("external", "hamming") == "external:hamming"
    assert descriptor_label("gist", None, [folder]) == "gist"


def test_jobs_with_matrix_files_alone_is_refused_as_describing_nothing(tmp_path: Path, cache_dir: Path) -> None:
    """Matrix files are not described: --jobs and --descriptor would change nothing, so they are
    refused as every option the inputs do not use is."""
    ref, query = _descriptors()
    np.save(tmp_path / "ref.npy", ref)
    np.save(tmp_path / "query.npy", query)
    matrices = ["localize", str(tmp_path / "query.npy"), "--map", str(tmp_path / "ref.npy"), "--metric", "l1",
                "--method", "threshold", "--out", str(tmp_path / "run.csv")]
    ends_in_one_error(runner.invoke(app, [*matrices, "--jobs", "2"]), 2,
                      "error: --jobs: applies to image folders, video files and ROS bags described on this machine")
    ends_in_one_error(runner.invoke(app, [*matrices, "--descriptor", "gist"]), 2,
                      "error: --descriptor: applies to image folders, video files and ROS bags only")
    assert not (tmp_path / "run.csv").exists()
    assert runner.invoke(app, matrices).exit_code == 0


@pytest.fixture(autouse=True)
def _in_tmp(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)  # results files without --out land here


def _bad_sources(tmp: Path) -> dict[str, tuple[list[str], int, str]]:
    ragged = _hloc_file(tmp / "ragged.h5", {"a.jpg": np.ones(8), "b/c.jpg": np.ones(9)})
    folder = tmp / "npys"
    (folder / "sub").mkdir(parents=True)
    np.save(folder / "a.jpg.npy", np.ones(8, np.float32))
    np.save(folder / "sub" / "b.jpg.npy", np.ones(9, np.float32))
    neither = tmp / "neither.h5"
    with h5py.File(neither, "w") as handle:
        handle["something"] = np.ones(3)
    hloc = _hloc_file(tmp / "ok.h5", {"db/a.jpg": np.ones(4)})
    return {
        "hloc rows of two lengths": (["--import", str(ragged), "--out", str(tmp / "x.h5")], 1,
                                     "'b/c.jpg/global_descriptor' holds 9 values, but 'a.jpg/global_descriptor' holds 8"),
        "npy files of two lengths": (["--import", str(folder), "--out", str(tmp / "x.h5")], 1,
                                     "sub/b.jpg.npy holds 9 values, but a.jpg.npy holds 8"),
        "neither layout": (["--import", str(neither)], 1, "neither a dataset 'descriptors' (N x D) nor hloc's groups"),
        "prefix matching nothing": (["--import", str(hloc), "--prefix", "query/", "--out", str(tmp / "x.h5")], 1,
                                    "no frame name begins with 'query/'"),
        "folder without --out": (["--import", str(folder)], 2, "--out: "),
        "prefix without --out": (["--import", str(hloc), "--prefix", "db/"], 2, "--prefix: applies to --import with --out only"),
        "out onto the source": (["--import", str(hloc), "--out", str(hloc)], 2, "is the file being imported"),
        "out not h5": (["--import", str(hloc), "--out", str(tmp / "x.csv")], 2, "a descriptor file is HDF5"),
    }


@pytest.mark.parametrize("case", ["hloc rows of two lengths", "npy files of two lengths", "neither layout",
                                  "prefix matching nothing", "folder without --out", "prefix without --out",
                                  "out onto the source", "out not h5"])
def test_bad_sources_are_one_line(case: str, tmp_path: Path, cache_dir: Path) -> None:
    args, code, message = _bad_sources(tmp_path)[case]
    ends_in_one_error(runner.invoke(app, ["describe", *args]), code, message)
    assert not (tmp_path / "x.h5").exists()  # nothing half-written


def test_a_matrix_file_without_a_recorded_metric_still_needs_one(tmp_path: Path, cache_dir: Path) -> None:
    feats = _hloc_file(tmp_path / "feats.h5", {f"img{i}.jpg": v for i, v in enumerate(_descriptors()[0])})
    ends_in_one_error(runner.invoke(app, ["localize", str(feats)]), 2, "--metric: ", "needs a metric", "imported descriptors")


def test_a_folder_against_a_matrix_of_other_descriptors_names_both(tmp_path: Path, cache_dir: Path) -> None:
    # a map of sad's length and metric from another tool differs in scale only: the error leads
    # with what the scale follows from, the two descriptors
    names = write_images(tmp_path / "query", 4)
    np.save(tmp_path / "map.npy", np.random.default_rng(0).integers(0, 256, (4, 1152)).astype(np.uint8))
    (tmp_path / "names.txt").write_text("\n".join(names))
    result = runner.invoke(app, ["localize", str(tmp_path / "query"), "--map", str(tmp_path / "map.npy"),
                                 "--map-names", str(tmp_path / "names.txt"), "--metric", "l1", "--method", "threshold",
                                 "--out", str(tmp_path / "run.csv")])
    ends_in_one_error(result, 1, "cannot be compared with", "descriptor sad vs external (describe both alike)")
    assert not (tmp_path / "run.csv").exists()


def test_an_entry_imported_by_an_earlier_reader_is_not_reused(tmp_path: Path, cache_dir: Path,
                                                             monkeypatch: pytest.MonkeyPatch) -> None:
    """The reader's version is part of an imported entry's key: after a change of how a format is
    read (a pandas CSV's header once made a frame of its own), the file is read again, never
    taken from the entry an earlier reader made."""
    from wiloc.cache.store import Cache
    from wiloc.description import matrix_import

    path = tmp_path / "m.csv"
    path.write_text("a.jpg,1,2\nb.jpg,3,4\n")
    first = matrix_import.import_matrix(path, Cache(cache_dir), None, "l1")
    again = matrix_import.import_matrix(path, Cache(cache_dir), None, "l1")
    assert (first.computed, again.computed, again.reused) == (2, 0, 2)
    monkeypatch.setattr(matrix_import, "READER_VERSION", matrix_import.READER_VERSION + 1)
    newer = matrix_import.import_matrix(path, Cache(cache_dir), None, "l1")
    assert (newer.computed, newer.reused) == (2, 0)
    assert newer.entry.key != first.entry.key


def test_a_run_on_imported_matrices_records_no_descriptor_parameters(tmp_path: Path, cache_dir: Path) -> None:
    """The command line passes the default descriptor's crop with matrix files too, and their
    runs' headers recorded sad's {"crop": "none"}, though no row of them was sad's: they record no
    parameters now, and rows given as ``external`` their own. A file written before still reads
    and draws."""
    from wiloc.localization.localizer import Localizer

    ref, query = _descriptors()
    np.save(tmp_path / "ref.npy", ref)
    np.save(tmp_path / "query.npy", query)
    _invoke("localize", tmp_path / "query.npy", "--map", tmp_path / "ref.npy", "--metric", "l1", "--method",
            "threshold", "--out", tmp_path / "run.csv")
    header = read_results(tmp_path / "run.csv").header
    assert (header.descriptor, header.descriptor_params) == ("external:l1", {})
    loc = Localizer(tmp_path / "ref.npy", descriptor="external", descriptor_params={"metric": "l1", "length": D},
                    method="threshold", metric="l1")
    loc.observe(query[0])
    assert loc.results().header.descriptor_params == {"metric": "l1", "length": D, "dtype": "float32"}

    text = (tmp_path / "run.csv").read_text()
    assert text.count("# descriptor_params: {}\n") == 1
    (tmp_path / "old.csv").write_text(text.replace("# descriptor_params: {}\n", '# descriptor_params: {"crop": "none"}\n'))
    assert read_results(tmp_path / "old.csv").header.descriptor_params == {"crop": "none"}
    _invoke("evaluate", tmp_path / "old.csv", "--matrix-plot", tmp_path / "matrix.png")
    assert (tmp_path / "matrix.png").stat().st_size > 0


@pytest.mark.parametrize("args", [["describe", "--import"], ["describe", "--out", "out.h5", "--import"],
                                  ["localize", "--metric", "l1", "-R", "1"]])
def test_names_given_a_folder_are_said_to_be_a_folder(args: list[str], tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """--names naming a folder was said not to exist, which it does."""
    monkeypatch.chdir(tmp_path)
    np.save(tmp_path / "m.npy", np.random.default_rng(0).random((3, 4)).astype(np.float32))
    (tmp_path / "names").mkdir()
    ends_in_one_error(runner.invoke(app, [*args, "m.npy", "--names", "names"]), 1,
                      "names: a folder, not a file of frame names")


@pytest.mark.parametrize("out", [[], ["--out", "again.h5"]])
def test_a_metric_overriding_the_recorded_one_is_said_to(out: list[str], tmp_path: Path,
                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """describe --import X.h5 --metric cosine, X.h5 recording sqeuclidean, took cosine silently."""
    monkeypatch.chdir(tmp_path)
    np.save(tmp_path / "m.npy", np.random.default_rng(0).random((3, 4)).astype(np.float32))
    assert runner.invoke(app, ["describe", "--import", "m.npy", "--metric", "sqeuclidean", "--out", "x.h5"]).exit_code == 0
    result = runner.invoke(app, ["describe", "--import", "x.h5", "--metric", "cosine", *out, "--json"])
    assert result.exit_code == 0, result.output
    said = "records the metric sqeuclidean; the one given (--metric cosine) overrides it"
    assert [line for line in json.loads(result.stdout)["warnings"] if said in line] != [], result.output
    assert said in result.stderr
    quiet = runner.invoke(app, ["describe", "--import", "x.h5", "--metric", "sqeuclidean", *out, "--json"])
    replaced = [f"note: replaced the existing descriptor file {name}" for name in out[1:]]  # again.h5, written above
    assert quiet.exit_code == 0 and json.loads(quiet.stdout)["warnings"] == replaced, quiet.output


def test_localize_with_a_metric_overriding_the_recorded_one_says_so(tmp_path: Path, cache_dir: Path,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """localize Q.h5 --map M.h5 --metric cosine, both recording l1, compared with cosine and said
    nothing; it says so once per file, as describe --import does. A .npy records no metric: the
    one given is its only one, and nothing is said."""
    monkeypatch.chdir(tmp_path)
    ref, query = _descriptors()
    np.save(tmp_path / "m.npy", ref)
    np.save(tmp_path / "q.npy", query)
    for name in ("m", "q"):
        _invoke("describe", "--import", f"{name}.npy", "--metric", "l1", "--out", f"{name}.h5")
    result = runner.invoke(app, ["localize", "q.h5", "--map", "m.h5", "--metric", "cosine", "--method", "threshold",
                                 "--out", "run.csv", "--json"])
    assert result.exit_code == 0, result.output
    said = [line for line in json.loads(result.stdout)["warnings"] if "overrides it" in line]
    assert said == [f"note: {tmp_path / name}.h5: records the metric l1; the one given (--metric cosine) overrides it"
                    for name in ("q", "m")], result.output
    assert read_results(tmp_path / "run.csv").header.metric == "cosine"
    quiet_runs = (["q.h5", "--map", "m.h5", "--metric", "l1"], ["q.npy", "--map", "m.npy", "--metric", "cosine"])
    for i, args in enumerate(quiet_runs):
        quiet = runner.invoke(app, ["localize", *args, "--method", "threshold", "--out", f"again{i}.csv", "--json"])
        assert quiet.exit_code == 0 and not any("overrides" in line for line in json.loads(quiet.stdout)["warnings"]), \
            quiet.output


def _other_outs(tmp: Path) -> dict[str, Path]:
    """Files of someone else's at --out: none of them a descriptor file --out wrote."""
    text = tmp / "victim.h5"
    text.write_text("notes of one's own\n")
    folder = tmp / "folder.h5"
    folder.mkdir()
    (folder / "kept.txt").write_text("kept\n")
    return {"hloc file": _hloc_file(tmp / "other-hloc.h5", {"db/a.jpg": np.ones(4)}), "text file": text,
            "folder": folder}


def _files(tmp: Path) -> list[tuple[Path, bytes | None]]:
    """What ``tmp`` holds besides the cache: each path and its bytes (None for a folder)."""
    return sorted((p.relative_to(tmp), p.read_bytes() if p.is_file() else None)
                  for p in tmp.rglob("*") if "cache" not in p.relative_to(tmp).parts)


@pytest.mark.parametrize("case", ["hloc file", "text file", "folder"])
def test_out_never_replaces_a_file_that_is_no_descriptor_file(case: str, tmp_path: Path, cache_dir: Path) -> None:
    """--out over another tool's .h5 (or any file it did not write) replaced it silently, exit 0."""
    feats = _hloc_file(tmp_path / "gf.h5", {f"db/img{i}.jpg": v for i, v in enumerate(_descriptors()[0])})
    out = _other_outs(tmp_path)[case]
    before = _files(tmp_path)
    result = runner.invoke(app, ["describe", "--import", str(feats), "--prefix", "db/", "--metric", "cosine",
                                 "--out", str(out)])
    ends_in_one_error(result, 1, f"error: {out}: ", "no wiloc descriptor file", "give another name, or remove it first")
    assert _files(tmp_path) == before  # nothing written, not even a temporary file
    with pytest.raises(WilocError, match="give another name, or remove it first"):
        api.import_descriptors(feats, metric="cosine", prefix="db/", out=out, cache=cache_dir)
    assert _files(tmp_path) == before


def test_out_replaces_a_descriptor_file_and_says_so(tmp_path: Path, cache_dir: Path) -> None:
    """A descriptor file --out wrote (an import redone) is replaced, said on stderr and in --json."""
    ref, query = _descriptors()
    feats = _hloc_file(tmp_path / "gf.h5", {**{f"db/img{i}.jpg": v for i, v in enumerate(ref)},
                                            **{f"query/img{i}.jpg": v for i, v in enumerate(query)}})
    out = tmp_path / "map.h5"
    first = runner.invoke(app, ["describe", "--import", str(feats), "--prefix", "db/", "--metric", "cosine",
                                "--out", str(out), "--json"])
    assert first.exit_code == 0 and json.loads(first.stdout)["warnings"] == [], first.output
    again = runner.invoke(app, ["describe", "--import", str(feats), "--prefix", "query/", "--metric", "l1",
                                "--out", str(out), "--json"])
    assert again.exit_code == 0, again.output
    assert json.loads(again.stdout)["warnings"] == [f"note: replaced the existing descriptor file {out}"]
    assert again.stderr.strip().splitlines() == [f"note replaced the existing descriptor file {out}"]
    names, matrix = read_external(out, None, "l1")
    assert recorded_metric(out) == "l1" and names == [f"img{i}.jpg" for i in range(N)]
    assert np.array_equal(matrix, query.astype(np.float16).astype(matrix.dtype))
    report = api.import_descriptors(feats, metric="cosine", prefix="db/", out=out, cache=cache_dir)
    assert report.notes == [f"replaced the existing descriptor file {out}"]
