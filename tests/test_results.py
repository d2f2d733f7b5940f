"""Results files: round trip, header, atomic write, bad files."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from helpers import ends_in_one_error
from typer.testing import CliRunner

from wiloc.cli import app
from wiloc.decisions import Decision, Decisions
from wiloc.errors import WilocError
from wiloc.evaluation.results import Results, ResultsStream, make_results, read_results, write_results
from wiloc.evaluation.results_header import ResultsHeader, parse_header
from wiloc.model import HistogramModel


def _decisions() -> Decisions:
    model = HistogramModel.from_range(0.0, 1.0, bins=4)
    model.add_same([0.1, 0.3])
    model.add_different([0.9])
    return Decisions(match=np.array([-1, 2, 0]), difference=np.array([np.nan, 0.25, 0.5]),
                     confidence=np.array([np.nan, 0.9, 0.1]), stage=np.array(["init", "update", "update"]),
                     columns={"m_r": np.array([np.nan, 0.7, 0.8])}, model=model, params={"init": 1},
                     ranking=np.array([[-1, -1], [2, 1], [0, -1]]))


def _made(header: ResultsHeader = ResultsHeader()) -> Results:  # noqa: B008 - ResultsHeader is frozen
    """The run of :func:`_decisions` over query frames a, b, c and map frames x, y, z."""
    return make_results(_decisions(), query_names=["a", "b", "c"], ref_names=["x", "y", "z"], header=header)


def test_round_trip_keeps_names_values_and_model(tmp_path: Path) -> None:
    path = tmp_path / "run.csv"
    write_results(path, make_results(_decisions(), query_names=["q,1.png", "q2.png", "q 3.png"],
                                     ref_names=["r0.png", "r1.png", "r#2.png"],
                                     header=ResultsHeader(method="online", query="/x")))
    back = read_results(path)
    assert back.method == "online"
    assert back.frames["frame"].tolist() == ["q,1.png", "q2.png", "q 3.png"]
    assert back.frames["match"].tolist() == ["", "r#2.png", "r0.png"]
    assert back.match_index.tolist() == [-1, 2, 0]
    assert np.isnan(back.confidence[0]) and back.confidence[1] == pytest.approx(0.9)
    assert back.frames["m_r"].iloc[1] == pytest.approx(0.7)
    assert back.ranking.tolist() == [[-1, -1], [2, 1], [0, -1]]
    assert back.header.params == {"init": 1}
    assert back.model is not None and back.model.b.tolist() == [1.0, 1.0, 0.0, 0.0]
    assert not list(tmp_path.glob(".*tmp"))


#: Every character that ends a line for a reader of the file: pandas' (\r, \n) or Python's (str.splitlines).
LINE_BREAKS = ("\r", "\n", "\r\n", "\x0b", "\x0c", "\x1c", "\x1d", "\x1e", "\x85", "\u2028", "\u2029")


@pytest.mark.parametrize("brk", LINE_BREAKS)
def test_a_line_break_in_a_frames_name_survives_a_write_and_a_read(tmp_path: Path, brk: str) -> None:
    """A carriage return in a name (Linux file names may hold one) was written unquoted, and
    pandas read the row as two: 'holds 5 rows, its header says 3'."""
    path = tmp_path / "run.csv"
    names, refs = [f"q{brk}0.png", "q1.png", f"{brk}q2.png"], ["x", "y", f"z{brk}"]
    write_results(path, make_results(_decisions(), query_names=names, ref_names=refs, header=ResultsHeader()))
    back = read_results(path)
    assert back.frames["frame"].tolist() == names
    assert back.frames["match"].tolist() == ["", refs[2], refs[0]]


@pytest.mark.parametrize("brk", LINE_BREAKS)
def test_a_line_break_in_a_frames_name_survives_a_followed_runs_rows(tmp_path: Path, brk: str) -> None:
    path = tmp_path / "live.csv"
    stream = ResultsStream(path, ResultsHeader(method="threshold", reference_frames=("x", f"y{brk}")), (),
                           resume=False)
    decision = Decision(match=1, difference=0.5, confidence=0.5, stage="update", frame=f"a{brk}b.png",
                        match_name=f"y{brk}")
    stream.append(decision)
    stream.close()
    again = ResultsStream(path, stream.header, (), resume=True)
    again.close()
    assert again.written_lines() == [stream.line(decision)]
    assert read_results(path).frames[["frame", "match"]].values.tolist() == [[f"a{brk}b.png", f"y{brk}"]]


@pytest.mark.parametrize("tail", ["\n", "   \n", " \r\n\n", "\n  "])
def test_a_followed_run_resumed_after_an_editors_blank_lines_appends_where_its_rows_end(tmp_path: Path,
                                                                                      tail: str) -> None:
    """Blank lines (or lines of spaces) at a followed file's end, which reading passes over, were
    kept when the run resumed, so that its next rows followed them and the file, blank lines
    between rows, was refused; a torn last row is still cut off."""
    path = tmp_path / "live.csv"
    header = ResultsHeader(method="threshold", reference_frames=("x", "y"))
    decisions = [Decision(match=k, difference=0.5, confidence=0.5, stage="update", frame=f"{name}.png",
                          match_name="xy"[k]) for k, name in enumerate("ab")]
    stream = ResultsStream(path, header, (), resume=False)
    stream.append(decisions[0])
    stream.close()
    with path.open("a", encoding="utf-8", newline="") as file:
        file.write(tail + "b.png,x,0.")  # a row torn after the editor's lines
    again = ResultsStream(path, stream.header, (), resume=True)
    assert again.written_lines() == [stream.line(decisions[0])]
    again.append(decisions[1])
    again.close()
    assert read_results(path).frames["frame"].tolist() == ["a.png", "b.png"]
    assert path.read_text(encoding="utf-8").endswith(stream.line(decisions[0]) + stream.line(decisions[1]))


def test_header_names_the_run(tmp_path: Path) -> None:
    path = tmp_path / "run.csv"
    write_results(path, _made(ResultsHeader(method="threshold", descriptor="sad", wiloc="0.1.0")))
    head = path.read_text(encoding="utf-8").splitlines()[:4]
    assert head[0] == "# wiloc-results: 1"
    assert "# method: threshold" in head and "# descriptor: sad" in head


def test_every_header_field_survives_a_write_and_a_read(tmp_path: Path) -> None:
    header = ResultsHeader(method="online", descriptor="external:cosine", descriptor_params={"crop": [1, 2]},
                           metric="cosine", mode="map", query="/q", map="/r", exclude_recent=7, wiloc="9.9",
                           train_query="/tq", train_map="/tr", query_digest="ab", map_digest="cd",
                           sampling={"every": 2, "fps": None, "start": "1.5s", "stop": None}, topic="/cam",
                           map_topic="/cam0", odometry_topic="/odom", rows="fabmap", fabmap_training=("/t 1", "/t'2"),
                           reference_left_out=((1, "w"), (4, "v")), extra={"note": "kept as text"})
    path = tmp_path / "run.csv"
    written = _made(header)
    write_results(path, written)
    assert read_results(path).header == written.header
    assert written.header.model is not None and written.header.frames == 3
    followed = replace(header, follow=True, params={"init": 1}, reference_frames=("x", "y"))  # no count, no model
    assert parse_header(followed.text().splitlines(), None) == followed
    assert "# follow: True" in followed.text() and "# model:" not in followed.text()


def test_the_maps_frames_left_out_have_a_line_only_when_there_are_some(tmp_path: Path) -> None:
    """``reference_left_out``: [position in the map's full order, name] pairs, read back as they
    were written; a run that left out no map frame writes no such line (its file as before)."""
    header = ResultsHeader(method="threshold", mode="map", reference_left_out=((1, "w"),))
    assert '# reference_left_out: [[1, "w"]]\n' in header.text()
    assert parse_header(header.text().splitlines(), None).reference_left_out == ((1, "w"),)
    assert "reference_left_out" not in ResultsHeader(method="threshold", mode="map").text()


@pytest.mark.parametrize("value", ['[["1", "w"]]', '[[1]]', '{"1": "w"}', '[[-1, "w"]]', '[[1, "w"], [1, "v"]]',
                                   '[[2, "w"], [1, "v"]]', '[[true, "w"]]'])
def test_a_left_out_list_no_run_writes_is_refused_naming_its_line(value: str) -> None:
    lines = ["# wiloc-results: 1", "# mode: map", f"# reference_left_out: {value}"]
    with pytest.raises(WilocError, match="line 3: header 'reference_left_out' must be"):
        parse_header(lines, Path("run.csv"))


def test_an_older_file_without_newer_keys_reads_with_their_defaults(tmp_path: Path) -> None:
    path, text = _written(tmp_path)
    kept = [line for line in text.splitlines()
            if not line.startswith(("# exclude_recent", "# descriptor", "# metric", "# wiloc:", "# model"))]
    path.write_text("\n".join(kept) + "\n", encoding="utf-8")
    header = read_results(path).header
    assert (header.exclude_recent, header.descriptor, header.descriptor_params, header.metric, header.model) == \
        (0, None, {}, "", None)
    assert header.query_digest is None and header.sampling is None and not header.follow


def test_a_header_key_this_version_does_not_know_is_kept_as_text(tmp_path: Path) -> None:
    path, text = _written(tmp_path)
    path.write_text(text.replace("# mode: map", "# mode: map\n# colour: {\"blue\": 1}"), encoding="utf-8")
    header = read_results(path).header
    assert header.extra == {"colour": '{"blue": 1}'} and header.mode == "map"
    again = tmp_path / "again.csv"
    write_results(again, read_results(path))
    assert "# colour: {\"blue\": 1}\n" in again.read_text(encoding="utf-8")


def test_not_a_results_file(tmp_path: Path) -> None:
    path = tmp_path / "other.csv"
    path.write_text("frame,match\na,b\n")
    with pytest.raises(WilocError, match="not a wiloc results file"):
        read_results(path)


def test_missing_column_and_duplicates(tmp_path: Path) -> None:
    path = tmp_path / "run.csv"
    write_results(path, _made())
    text = path.read_text(encoding="utf-8")
    path.write_text(text.replace("confidence", "conf"), encoding="utf-8")
    with pytest.raises(WilocError, match="missing column"):
        read_results(path)
    lines = text.replace("# frames: 3", "# frames: 4").splitlines()
    path.write_text("\n".join(lines + [lines[-1]]) + "\n", encoding="utf-8")
    with pytest.raises(WilocError, match=f"line {len(lines) + 1}: frame 'c' again \\(line {len(lines)} gives it\\)"):
        read_results(path)


def test_a_row_without_a_frame_name_is_refused_naming_its_line(tmp_path: Path) -> None:
    """A row whose frame cell an edit emptied was read as a frame named '' and scored."""
    path = tmp_path / "run.csv"
    write_results(path, _made())
    lines = path.read_text(encoding="utf-8").splitlines()
    row = lines.index(next(line for line in lines if line.startswith("b,")))
    lines[row] = lines[row][1:]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    with pytest.raises(WilocError, match=f"line {row + 1}: the frame cell is empty"):
        read_results(path)


def test_missing_file() -> None:
    with pytest.raises(WilocError, match="does not exist"):
        read_results(Path("/nonexistent/run.csv"))


def test_cut_file_and_binary_file_are_refused(tmp_path: Path) -> None:
    path = tmp_path / "run.csv"
    write_results(path, _made())
    text = path.read_text(encoding="utf-8")
    path.write_text(text[: text.rindex("\n", 0, len(text) - 1) + 1], encoding="utf-8")
    with pytest.raises(WilocError, match="holds 2 rows, its header says 3"):
        read_results(path)
    path.write_bytes(b"\xff\xfe\x00binary")
    with pytest.raises(WilocError, match="not UTF-8"):
        read_results(path)


def _written(tmp_path: Path) -> tuple[Path, str]:
    path = tmp_path / "run.csv"
    write_results(path, _made(ResultsHeader(mode="map", exclude_recent=10)))
    return path, path.read_text(encoding="utf-8")


@pytest.mark.parametrize("edit, message", [
    (lambda t: t.replace("b,z,0.25,0.9", "b,z,0.25,high"), r"line \d+: confidence 'high' is not a number"),
    (lambda t: t.replace("b,z,0.25", "b,w,0.25"), r"line \d+: match 'w' is not a frame of the map"),
    (lambda t: "\n".join(l for l in t.splitlines() if not l.startswith("# reference_frames")) + "\n",
     "no 'reference_frames' header"),
    (lambda t: t.replace('# reference_frames: ["x", "y", "z"]', "# reference_frames: 3"),
     "'reference_frames' must be a list"),
    (lambda t: t.replace("# exclude_recent: 10", "# exclude_recent: ten"), "'exclude_recent' must be a whole number"),
    (lambda t: t.replace("# frames: 3", "# frames: three"), "'frames' must be a whole number"),
    (lambda t: t.replace('# params: {"init": 1}', "# params: [1]"), "header 'params' must be a JSON object"),
    (lambda t: t.replace('["x", "y", "z"]', '["x", "y", "x"]'), "header 'reference_frames' names 'x' twice"),
    (lambda t: t.replace('"edges": [', '"edges": ["x", '), "header 'model' is not a histogram model"),
    (lambda t: t.replace(",2 1\n", ",2 one\n"), r"line \d+: ranking '2 one' is not positions separated by spaces"),
    (lambda t: t.replace(",2 1\n", ",2 7\n"), r"line \d+: ranking names position 7; the map has 3 frames"),
    (lambda t: t.replace(",2 1\n", ",2 2\n"), r"line \d+: ranking names a frame twice"),
    (lambda t: t.replace(",2 1\n", ",1 2\n"), r"line \d+: ranking does not start with the match"),
    (lambda t: t.replace(",2 1\n", ",\n"), r"line \d+: ranking does not start with the match"),
    (lambda t: t.replace("# mode: map", "# mode: sequence").replace("# map: \n", "# map: /r\n"),
     "header 'map' names a map, but 'mode' is sequence: a sequence-mode run is its own map"),
    (lambda t: t.replace("# mode: map", "# mode: sequence").replace("# map: \n", "# map: \n# map_digest: 0a1b\n"),
     "header 'map_digest' names a map"),
    (lambda t: t.replace("# mode: map", "# mode: seq"), "line 5: header 'mode' must be map or sequence, got 'seq'"),
    (lambda t: t.replace("# mode: map", "# mode: map\n# mode: sequence"),
     r"line 6: header 'mode' again \(line 5 gives it\): a run writes each key once"),
    (lambda t: t.replace("# mode: map", "# mode: map\n# rows: evidence"),
     r"line 6: header 'rows' must be fabmap \(a run on FAB-MAP's evidence\), got 'evidence'"),
    (lambda t: t.replace("stage,m_r,", "stage,ranking,"), r"line \d+: column 'ranking' twice"),
    (lambda t: t.replace("stage,m_r,", "stage,,"), r"line \d+: column 6 has no name"),
    (lambda t: t.replace("b,z,0.25,0.9,update,0.7,2 1", "b,z,0.25"),
     r"line \d+: 3 cell\(s\), where the column line \(line \d+\) names 7 columns"),
    (lambda t: t.replace(",2 1\n", ",2 1,x\n"), r"line \d+: 8 cell\(s\), where the column line \(line \d+\) names 7"),
])
def test_a_results_file_no_run_writes_is_refused_naming_the_line(tmp_path: Path, edit, message: str) -> None:
    path, text = _written(tmp_path)
    path.write_text(edit(text), encoding="utf-8")
    with pytest.raises(WilocError, match=message):
        read_results(path)


def test_a_stage_of_a_method_registered_outside_the_package_is_read(tmp_path: Path) -> None:
    path, text = _written(tmp_path)  # a registered method may say what it did in its own words
    path.write_text(text.replace("b,z,0.25,0.9,update,", "b,z,0.25,0.9,warmup,"), encoding="utf-8")
    assert "warmup" in read_results(path).frames["stage"].tolist()


def test_a_replaced_file_keeps_its_mode_and_killed_writers_leave_nothing(tmp_path: Path) -> None:
    import os
    import subprocess
    import sys
    path, _ = _written(tmp_path)
    assert path.stat().st_mode & 0o777 == 0o666 & ~_umask()
    os.chmod(path, 0o640)
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True, check=True).stdout.strip()
    orphan = tmp_path / f".run.csv.{dead}.abc123.tmp"
    orphan.write_text("half a file")
    assert write_results(path, _made())
    assert path.stat().st_mode & 0o777 == 0o640
    assert not orphan.exists()


def test_a_write_that_fails_leaves_the_old_file_and_says_so_in_one_line(tmp_path: Path,
                                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    import pandas as pd

    from wiloc.evaluation import results

    path, text = _written(tmp_path)

    def full_disk(out: object, frames: pd.DataFrame) -> None:
        out.write("frame,match\na,x\n")  # type: ignore[attr-defined]  # a start, then the disk is full
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(results, "_write_table", full_disk)
    with pytest.raises(WilocError, match=r"cannot write the results file \(No space left on device\)"):
        write_results(path, _made())
    assert path.read_text(encoding="utf-8") == text
    assert [p.name for p in tmp_path.iterdir()] == [path.name]  # no temporary file left


def _umask() -> int:
    import os
    current = os.umask(0)
    os.umask(current)
    return current


def test_a_name_no_file_can_have_is_refused_naming_the_file(tmp_path: Path) -> None:
    """A name over 255 bytes was OSError's (File name too long) from Results.save, not the
    WilocError naming the file that every other failed write is."""
    path = tmp_path / ("r" * 300 + ".csv")
    with pytest.raises(WilocError, match="cannot write the results file: no file can have this name"):
        _made().save(path)
    assert list(tmp_path.iterdir()) == []


def test_a_file_without_a_method_line_is_refused_where_the_methods_are_known(tmp_path: Path) -> None:
    from wiloc.methods.registry import METHODS

    path, text = _written(tmp_path)
    path.write_text(text.replace("# method: \n", ""), encoding="utf-8")
    assert read_results(path).method == ""  # no methods given: any name, none too
    with pytest.raises(WilocError, match="no 'method' header: the method that wrote the file is unknown"):
        read_results(path, METHODS)


@pytest.mark.parametrize("name, meant", [("catgrap", "catgraph"), ("Catgraph", "catgraph"), ("cat-graph", "catgraph"),
                                         ("ONLINE", "online"), ("seq_slam", "seqslam"), ("treshold", "threshold"),
                                         ("ratoi", "ratio")])
def test_a_method_name_close_to_a_registered_one_is_refused_naming_it(tmp_path: Path, name: str, meant: str) -> None:
    """A misspelt method (catgrap) was read as a method another program registers: its columns and
    differences unchecked, so a renamed column or a bad value catgraph's checks refuse passed.
    Names are close without case, '-' and '_', and to a program's own registered method too."""
    from wiloc.methods.registry import METHODS

    path = tmp_path / "run.csv"
    write_results(path, _made(ResultsHeader(method=name)))
    line = path.read_text(encoding="utf-8").splitlines().index(f"# method: {name}") + 1
    with pytest.raises(WilocError, match=rf"run.csv: line {line}: method '{name}' is not registered: "
                                         rf"did you mean '{meant}'\?"):
        read_results(path, {**METHODS, "ratio": METHODS["online"]})


@pytest.mark.parametrize("name", ["ratio", "offline", "random", "mymethod"])
def test_a_method_name_resembling_no_registered_one_is_read_as_another_program_s(tmp_path: Path, name: str) -> None:
    """A method a program of its own registers (docs/architecture.md) is read where it is not
    registered, its columns unchecked, and where it is as that method's."""
    from wiloc.methods.registry import METHODS

    path = tmp_path / "run.csv"
    write_results(path, _made(ResultsHeader(method=name)))
    assert read_results(path, METHODS).frames["m_r"].iloc[1] == pytest.approx(0.7)
    assert read_results(path, {**METHODS, name: METHODS["online"]}).method == name  # m_r: online's column


def test_every_built_in_method_name_is_read_as_its_method(tmp_path: Path) -> None:
    from wiloc.methods.registry import METHODS

    path = tmp_path / "run.csv"
    for name, method in METHODS.items():
        decisions = replace(_decisions(), columns={}, ranking=_decisions().ranking if method.ranks else None)
        write_results(path, make_results(decisions, query_names=["a", "b", "c"], ref_names=["x", "y", "z"],
                                         header=ResultsHeader(method=name)))
        assert read_results(path, METHODS).method == name


def test_evaluate_refuses_a_misspelt_method_in_one_line(tmp_path: Path) -> None:
    path = tmp_path / "run.csv"
    write_results(path, _made(ResultsHeader(method="catgrap")))
    ends_in_one_error(CliRunner().invoke(app, ["evaluate", str(path)]), 1,
                      f"{path}: line 2: method 'catgrap' is not registered: did you mean 'catgraph'?")


@pytest.mark.parametrize("header, legitimate", [
    (ResultsHeader(method="fabmap", descriptor="bow", rows="fabmap"), True),
    (ResultsHeader(method="catgraph", descriptor="bow", rows="fabmap"), True),
    (ResultsHeader(method="catgraph", descriptor="bow", follow=True), True),  # an older followed file: no rows line
    (ResultsHeader(method="catgraph", descriptor="sad"), False),
    (ResultsHeader(method="online", descriptor="bow"), False)])
def test_a_negative_difference_is_read_only_from_a_run_on_fabmaps_evidence(header: ResultsHeader, legitimate: bool,
                                                                          tmp_path: Path) -> None:
    """Every metric's differences are >= 0; FAB-MAP's evidence gives -r, of either sign. A
    negative difference edited into a run on differences was read silently."""
    from wiloc.methods.registry import METHODS

    decisions = replace(_decisions(), columns={})  # m_r: online's column, which these methods do not write
    decisions.difference[1] = -2.5
    path = tmp_path / "run.csv"
    write_results(path, make_results(decisions, query_names=["a", "b", "c"], ref_names=["x", "y", "z"], header=header))
    if legitimate:
        assert read_results(path, METHODS).frames["difference"].iloc[1] == -2.5
    else:
        with pytest.raises(WilocError, match=r"line \d+: difference -2.5 is not a finite number >= 0"):
            read_results(path, METHODS)


@pytest.mark.parametrize("brk", LINE_BREAKS)
def test_a_line_break_in_a_header_value_survives_a_write_a_read_and_a_resume(tmp_path: Path, brk: str) -> None:
    """A query folder named with a line break split its header line: the file was unreadable
    ('unreadable table') for \\r and \\n, and a followed run could not resume it ('malformed
    header line') for the breaks only str.splitlines knows (\\x0b, \\x85, \\u2028 ...)."""
    header = ResultsHeader(method="threshold", mode="map", query=f"/q{brk}day", map=f"/m{brk}", topic='"quoted"',
                           extra={"note": f"a{brk}b"}, reference_frames=("x", "y", "z"))
    path = tmp_path / "run.csv"
    write_results(path, _made(header))
    back = read_results(path).header
    assert (back.query, back.map, back.topic, back.extra) == (header.query, header.map, header.topic, header.extra)
    live = tmp_path / "live.csv"
    ResultsStream(live, header, (), resume=False).close()
    again = ResultsStream(live, header, (), resume=True)
    again.close()
    assert read_results(live).header.query == header.query



@pytest.mark.parametrize("column, renamed", [("m_r", "new_plac"), ("m_r", "novelty"), ("ranking", "rank")])
def test_a_column_the_method_does_not_write_is_refused_naming_it(tmp_path: Path, column: str, renamed: str) -> None:
    """A renamed column (new_place as new_plac) was read as if the run had no such values: an
    online run's without P(new place). Columns the file's method writes are read."""
    from wiloc.methods.registry import METHODS

    path = tmp_path / "run.csv"
    write_results(path, _made(ResultsHeader(method="online")))
    lines = path.read_text(encoding="utf-8").splitlines(keepends=True)
    header = next(i for i, line in enumerate(lines) if line.startswith("frame,"))
    path.write_text("".join(lines[:header] + [lines[header].replace("m_r", "new_place")] + lines[header + 1:]),
                    encoding="utf-8")
    assert read_results(path, METHODS).new_place is not None
    path.write_text("".join(lines[:header] + [lines[header].replace(column, renamed)] + lines[header + 1:]),
                    encoding="utf-8")
    with pytest.raises(WilocError, match=rf"line {header + 1}: unknown column\(s\) '{renamed}': the method online "
                                         "writes frame, match, difference, confidence, stage, m_r, new_place, ranking"):
        read_results(path, METHODS)


def test_a_row_of_other_cells_than_columns_names_its_line_and_line_ends_of_any_kind_read_alike(tmp_path: Path) -> None:
    """A row cut short was filled with empty cells (so read as an undecided frame, or refused for
    a ranking it never had); an editor's line ends (CR LF, CR alone, mixed) read the same table."""
    path, text = _written(tmp_path)
    lines = text.splitlines()
    column_line = lines.index("frame,match,difference,confidence,stage,m_r,ranking") + 1
    expected = read_results(path).frames
    for ends in ("\r\n", "\r", None):
        mixed = "".join(line + (ends or ("\r\n" if i % 2 else "\n")) for i, line in enumerate(lines))
        path.write_bytes(mixed.encode("utf-8"))
        assert read_results(path).frames.equals(expected)
    path.write_text("\n".join(lines[:-1] + ["c,x,0.5"]) + "\n", encoding="utf-8")
    with pytest.raises(WilocError, match=rf"line {len(lines)}: 3 cell\(s\), where the column line \(line {column_line}\) "
                                         "names 7 columns"):
        read_results(path)


@pytest.mark.parametrize("edit", [
    lambda text: text + "   \n", lambda text: text + "  ", lambda text: text + " \t \n\n",
    lambda text: text + "\n  \n", lambda text: text.replace("\n", "\r\n") + "  \r\n",
    lambda text: text.replace("\n", "\r\n") + " \r\n\r\n",
])
def test_lines_of_spaces_at_a_tables_end_read_as_the_blank_lines_they_look(tmp_path: Path, edit) -> None:
    """An editor's last lines of spaces (or of spaces and a CR) were refused as a row of one cell,
    where blank lines there read; between rows such a line is a blank line in the table, refused
    naming its line, and spaces between a row's data are a row of one cell still."""
    path, text = _written(tmp_path)
    expected = read_results(path).frames
    path.write_text(edit(text), encoding="utf-8", newline="")
    assert read_results(path).frames.equals(expected)
    lines = text.splitlines()
    path.write_text("\n".join([*lines[:-1], "   ", lines[-1]]) + "\n", encoding="utf-8")
    with pytest.raises(WilocError, match=rf"line {len(lines)}: a blank line in the table, where a run writes none"):
        read_results(path)
    path.write_text("\n".join([*lines[:-1], lines[-1].replace(",", " ")]) + "\n", encoding="utf-8")
    with pytest.raises(WilocError, match=rf"line {len(lines)}: 1 cell\(s\), where the column line"):
        read_results(path)
