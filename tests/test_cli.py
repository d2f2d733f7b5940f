"""The command line end to end on small generated traversals: output, --json, errors, exit codes."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from helpers import places, write_traversal
from typer.testing import CliRunner

from wiloc.cli import app
from wiloc.errors import UsageError

runner = CliRunner()


@pytest.fixture
def route(tmp_path: Path, cache_dir: Path) -> tuple[Path, Path]:
    """A reference and a darker, noisier query over the same 40 places."""
    scenes = places(40)
    return (write_traversal(tmp_path / "ref", scenes, 1.0, 1),
            write_traversal(tmp_path / "query", scenes, 0.7, 2))


@pytest.fixture
def titles(monkeypatch: pytest.MonkeyPatch) -> dict[str, str]:
    """The title of each figure drawn from now on, by its first words (up to a colon)."""
    from wiloc.figures import plots

    drawn: dict[str, str] = {}
    titled = plots._title
    monkeypatch.setattr(plots, "_title", lambda fig, title: (drawn.update({title.split(":")[0]: title}),
                                                             titled(fig, title))[1])
    return drawn


def _json(result) -> object:
    assert result.exit_code == 0, result.output
    return json.loads(result.stdout)


def test_describe_reports_and_reuses_cache(route: tuple[Path, Path]) -> None:
    ref, _ = route
    first = _json(runner.invoke(app, ["describe", str(ref), "--json", "--jobs", "1"]))["results"]
    assert first[0]["frames"] == 40 and first[0]["computed"] == 40 and first[0]["shape"] == [40, 1152]
    second = _json(runner.invoke(app, ["describe", str(ref), "--json", "--jobs", "1"]))["results"]
    assert second[0]["computed"] == 0 and second[0]["reused"] == 40
    table = runner.invoke(app, ["describe", str(ref), "--jobs", "1"])
    assert table.exit_code == 0 and "reused" in table.stdout


def test_missing_folder_is_one_line_error(tmp_path: Path, cache_dir: Path) -> None:
    result = runner.invoke(app, ["describe", str(tmp_path / "nope")])
    assert result.exit_code == 1
    assert "Traceback" not in result.output
    assert str(tmp_path / "nope") in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1


def test_names_that_look_like_emoji_codes_are_printed_as_they_are(route: tuple[Path, Path], tmp_path: Path,
                                                                  cache_dir: Path) -> None:
    """A path or option value holding ':name:' (a colon-separated name, a slice such as 1:100:2) is
    printed verbatim in errors and tables, not turned into an emoji."""
    result = runner.invoke(app, ["describe", str(tmp_path / "x:thumbs_up:y")])
    assert result.exit_code == 1 and "x:thumbs_up:y" in result.stderr and "\N{THUMBS UP SIGN}" not in result.stderr
    ref, query = route
    runs = tmp_path / "a:smile:b"
    runs.mkdir()
    made = runner.invoke(app, ["localize", str(query), "--map", str(ref), "--method", "threshold",
                               "--out", str(runs / "query-threshold.csv")], env={"COLUMNS": "300"})
    assert made.exit_code == 0, made.output
    assert "a:smile:b" in made.stdout and "\N{SMILING FACE WITH OPEN MOUTH AND SMILING EYES}" not in made.stdout
    assert f"results in {runs};" in made.stdout  # one line, however much longer than the table: to be copied


def test_localize_evaluate_compare(route: tuple[Path, Path], tmp_path: Path) -> None:
    ref, query = route
    runs = tmp_path / "runs"
    runs.mkdir()  # an output file's folder must exist (test_bad_inputs: "out in a missing folder")
    for method in ("online", "threshold"):
        rows = _json(runner.invoke(app, ["localize", str(query), "--map", str(ref), "--method", method,
                                         "--out", str(runs / f"query-{method}.csv"), "--json"]))["runs"]
        assert rows[0]["frames"] == 40 and rows[0]["decided"] == 40
        assert (rows[0]["method"], rows[0]["descriptor"], rows[0]["traversal"]) == (method, "sad", "query")
    metrics = _json(runner.invoke(app, ["evaluate", str(runs / "query-online.csv"), "--gt", "aligned",
                                        "--json"]))["runs"]
    assert metrics[0]["frames"] == 40 and 0.0 <= metrics[0]["recall_at_100"] <= 1.0
    assert metrics[0]["recall_at_1"] > 0.8  # the scenes are distinct; nearest neighbours are right
    fig5 = tmp_path / "fig5.png"
    table = _json(runner.invoke(app, ["compare", str(runs / "query-online.csv"), str(runs / "query-threshold.csv"),
                                      "--gt", "aligned", "--threshold-plot", str(fig5), "--json"]))
    assert {row["method"] for row in table["runs"]} == {"online", "threshold"}
    assert {row["precision"] for row in table["table2"]} == {100.0, 99.0}
    assert fig5.stat().st_size > 0


def test_sequence_mode_with_too_few_frames_writes_nothing(route: tuple[Path, Path], tmp_path: Path) -> None:
    ref, _ = route
    out = tmp_path / "seq.csv"
    result = runner.invoke(app, ["localize", str(ref), "--init", "100", "--out", str(out)])
    assert result.exit_code == 1
    assert "too few" in result.stderr and "Traceback" not in result.output
    assert not out.exists()


def test_map_with_one_frame_is_refused(route: tuple[Path, Path], tmp_path: Path) -> None:
    _, query = route
    single = tmp_path / "single"
    single.mkdir()
    (single / "img0.png").write_bytes((query / "img0.png").read_bytes())
    result = runner.invoke(app, ["localize", str(query), "--map", str(single)])
    assert result.exit_code == 1 and "at least 2" in result.stderr


def test_evaluate_rejects_a_foreign_csv(tmp_path: Path) -> None:
    bad = tmp_path / "x.csv"
    bad.write_text("a,b\n1,2\n")
    result = runner.invoke(app, ["evaluate", str(bad)])
    assert result.exit_code == 1 and "not a wiloc results file" in result.stderr


def test_help_shows_examples() -> None:
    for command in ([], ["describe"], ["localize"], ["evaluate"], ["compare"], ["demo"]):
        result = runner.invoke(app, [*command, "--help"])
        assert result.exit_code == 0 and "Example" in result.stdout


def test_catgraph_with_odometry_is_reproducible(route: tuple[Path, Path], tmp_path: Path) -> None:
    ref, query = route
    for name in ("ref.csv", "query.csv"):
        lines = ["name,distance"] + [f"img{i}.png,{1.0 if i else 0.0}" for i in range(40)]
        (tmp_path / name).write_text("\n".join(lines) + "\n")
    outs = []
    for run in ("a", "b"):
        out = tmp_path / f"{run}.csv"
        rows = _json(runner.invoke(app, ["localize", str(query), "--map", str(ref), "--method", "catgraph",
                                         "--odometry", str(tmp_path / "query.csv"),
                                         "--map-odometry", str(tmp_path / "ref.csv"), "--seed", "3",
                                         "--particles", "500", "--reseed", "0.02", "--step-noise", "0.4",
                                         "--out", str(out), "--json"]))["runs"]
        assert rows[0]["frames"] == 40
        outs.append(out.read_text())
    assert outs[0] == outs[1]
    assert '"reseed": 0.02' in outs[0] and '"step_noise": 0.4' in outs[0] and '"particles": 500' in outs[0]
    assert "new_place" in outs[0].splitlines()[-41]


def test_sequence_mode_takes_the_traversals_odometry(route: tuple[Path, Path], tmp_path: Path) -> None:
    """Without --map, catgraph's map is the traversal itself, placed by the query's --odometry."""
    _, query = route
    (tmp_path / "odo.csv").write_text("name,distance\n" + "".join(f"img{i}.png,{2.0 if i else 0.0}\n" for i in range(40)))
    out = tmp_path / "loop.csv"
    result = runner.invoke(app, ["localize", str(query), "--method", "catgraph", "--frontier", "10",
                                 "--odometry", str(tmp_path / "odo.csv"), "--out", str(out)])
    assert result.exit_code == 0, result.stderr
    assert '"odometry": true' in out.read_text()
    result = runner.invoke(app, ["localize", str(query), "--method", "catgraph", "--frontier", "10",
                                 "--map-odometry", str(tmp_path / "odo.csv")])
    assert result.exit_code == 2 and "--map-odometry: applies to map mode (--map) only" in result.stderr


def test_odometry_missing_a_frame_is_reported(route: tuple[Path, Path], tmp_path: Path) -> None:
    ref, query = route
    (tmp_path / "odo.csv").write_text("img0.png,0\nimg1.png,1\n")
    result = runner.invoke(app, ["localize", str(query), "--map", str(ref), "--method", "catgraph",
                                 "--odometry", str(tmp_path / "odo.csv"), "--map-odometry", str(tmp_path / "odo.csv")])
    assert result.exit_code == 1 and "no odometry for 38 frame(s)" in result.stderr


def test_describe_list_shows_entries(route: tuple[Path, Path]) -> None:
    ref, query = route
    assert runner.invoke(app, ["describe", str(ref), str(query), "--jobs", "1"]).exit_code == 0
    entries = _json(runner.invoke(app, ["describe", "--list", "--json"]))["results"]
    assert sorted(Path(e["folder"]).name for e in entries) == ["query", "ref"]
    assert all(e["frames"] == 40 and e["complete"] for e in entries)
    table = runner.invoke(app, ["describe", "--list"])
    assert table.exit_code == 0 and "sad" in table.stdout


def test_external_matrices_localize_and_nan_is_refused(tmp_path: Path, cache_dir: Path) -> None:
    rng = np.random.default_rng(0)
    for name in ("q", "r"):
        np.save(tmp_path / f"{name}.npy", rng.random((20, 8)).astype(np.float32))
    assert runner.invoke(app, ["describe", "--import", str(tmp_path / "q.npy"), "--metric", "cosine"]).exit_code == 0
    result = runner.invoke(app, ["localize", str(tmp_path / "q.npy"), "--map", str(tmp_path / "r.npy"),
                                 "--metric", "cosine", "--out", str(tmp_path / "ok.csv")])
    assert result.exit_code == 0, result.output
    bad = tmp_path / "nan.npy"
    np.save(bad, np.full((5, 8), np.nan, dtype=np.float32))
    result = runner.invoke(app, ["localize", str(bad), "--map", str(tmp_path / "r.npy"), "--metric", "cosine"])
    assert result.exit_code == 1 and str(bad) in result.stderr and "Traceback" not in result.output


def test_the_four_verbs_are_package_functions() -> None:
    import wiloc
    import wiloc.description.describing  # a submodule import must not shadow a verb
    from wiloc import api
    assert all(callable(getattr(wiloc, verb)) and getattr(wiloc, verb) is getattr(api, verb)
               for verb in ("describe", "localize", "evaluate", "compare"))


def test_localize_names_frames_it_left_out(route: tuple[Path, Path]) -> None:
    ref, query = route
    (query / "img5.png").write_bytes(b"")
    result = runner.invoke(app, ["localize", str(query), "--map", str(ref), "--method", "threshold",
                                 "--jobs", "1", "--out", str(query.parent / "t.csv")])
    assert result.exit_code == 0, result.output
    assert f"skipped {query / 'img5.png'}" in result.stderr
    assert "img5.png" not in (query.parent / "t.csv").read_text().split("frame,match")[1]


def test_bad_options_are_usage_errors(route: tuple[Path, Path], tmp_path: Path) -> None:
    ref, query = route
    for args in (["describe", str(ref), "--descriptor", "foo"],
                 ["localize", str(query), "--map", str(ref), "--descriptor", "foo"],
                 ["localize", str(query), "--map", str(ref), "--crop", "bogus"],
                 ["localize", str(query), "--map", str(ref), "-R", "-3"],
                 ["localize", str(query), "--map", str(ref), "--method", "nope"],
                 ["localize", str(query), "--map", str(ref), "--method", "threshold", "--model-plot", "m.png"],
                 ["localize", str(query), "--map", str(ref), "--method", "online", "--particles", "100"],
                 ["localize", str(query), "--map", str(ref), "--method", "catgraph", "--particles", "0"],
                 ["localize", str(query), "--map", str(ref), "--method", "catgraph", "--sequence-speeds", "1,x"],
                 ["localize", str(query), "--map", str(ref), "--method", "online", "--odometry", str(ref)],
                 ["localize", str(query), "--method", "seqslam"]):
        result = runner.invoke(app, args)
        assert result.exit_code == 2, (args, result.output)
        assert "Traceback" not in result.output and len(result.stderr.strip().splitlines()) == 1
    # catgraph runs without a map (sequence mode), on a traversal longer than its recent window and frontier
    result = runner.invoke(app, ["localize", str(query), "--method", "catgraph"])
    assert result.exit_code == 1 and "too few for sequence mode with frontier=60" in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1


def test_options_of_other_methods_name_the_method_and_library_errors_name_flags(
        route: tuple[Path, Path]) -> None:
    ref, query = route
    result = runner.invoke(app, ["localize", str(query), "--map", str(ref), "--particles", "100"])
    assert result.exit_code == 2
    assert result.stderr.strip() == ("error: --particles: method 'online' takes no such option "
                                     "(it is an option of catgraph)")
    result = runner.invoke(app, ["localize", str(query), "--map", str(ref), "--method", "catgraph", "--seed", "-1"])
    assert result.exit_code == 2 and result.stderr.strip() == "error: --seed: must be >= 0, got -1"


def test_help_groups_method_options_with_their_defaults() -> None:
    result = runner.invoke(app, ["localize", "--help"], env={"COLUMNS": "200"})
    assert result.exit_code == 0
    text = result.output
    for panel in ("online options", "catgraph options", "threshold options", "trained options"):
        assert panel in text
    catgraph = text[text.index("catgraph options"):]
    assert "--particles" in catgraph and "2000" in catgraph and "0.5,2/3,1,1.5,2" in catgraph


def test_a_list_default_typed_as_the_help_shows_it_is_the_default() -> None:
    """A researcher copies a default from the help to vary one of its numbers: typed unchanged, it
    must give the same parameters (0.333333 for 1/3 gave other decisions)."""
    from wiloc.cli.params import method_options

    lists = [option for option in method_options().values() if option.first.kind == "floats" and option.shared]
    assert any(1 / 3 in option.first.default for option in lists)
    for option in lists:
        assert option.parse(option.default()) == tuple(option.first.default), option.name


def test_a_list_default_shows_its_numbers_as_they_are_typed() -> None:
    """--sequence-speeds's default showed 1/3 as 0.3333333333333333, which no one types: a number
    that no short decimal is shows, and is taken, as the fraction it is."""
    from wiloc.cli.params import method_options

    shown = runner.invoke(app, ["localize", "--help"], env={"COLUMNS": "200"}).output
    assert "[default: 1/3,0.5,2/3,1,1.5,2,3,-0.5,-2/3,-1,-1.5,-2]" in shown and "0.333" not in shown
    speeds = method_options()["sequence_speeds"]
    assert speeds.parse("1/3, -2/3,1e-3") == (1 / 3, -2 / 3, 0.001)
    for bad in ("1/0", "1/2/3", "one/3"):
        with pytest.raises(UsageError, match=f"^--sequence-speeds: give comma-separated numbers, got '{bad}'$"):
            speeds.parse(bad)


def test_the_help_offers_no_value_the_command_line_cannot_take() -> None:
    """An option with a default takes a value of its type: its help may not offer 'none' (a
    parameter's None, which only the Python API can pass) unless 'none' is one of its choices."""
    from wiloc.cli.params import descriptor_options, method_options

    for option in [*method_options().values(), *descriptor_options().values()]:
        if option.default() is not None and "none" not in (option.first.choices or ()):
            assert "none" not in option.help().lower(), (option.name, option.help())
    shown = runner.invoke(app, ["localize", "--help"], env={"COLUMNS": "200"}).output
    assert "--seed" in shown and "none: a fresh one" not in shown


def test_an_option_methods_describe_differently_shows_each_description() -> None:
    from dataclasses import replace

    from wiloc.cli.params import DeclaredOption, method_options
    from wiloc.methods.registry import METHODS
    from wiloc.parameters import declared

    seed = method_options()["seed"]
    assert len(seed.by_owner) > 1
    for method in seed.by_owner:
        [own] = [d.help for d in declared(METHODS[method].Params) if d.name == "seed"]
        assert f"{method}: {own}" in seed.help()
    bins = method_options()["bins"]  # the same words: said once
    same = DeclaredOption("bins", {owner: replace(bins.first, help="Histogram bins.") for owner in ("a", "b")})
    assert same.help().startswith("Histogram bins.") and "a:" not in same.help()


def test_map_too_short_for_exclude_recent(route: tuple[Path, Path]) -> None:
    ref, query = route
    result = runner.invoke(app, ["localize", str(query), "--map", str(ref), "-R", "39"])
    assert result.exit_code == 1 and str(ref) in result.stderr and "exclude_recent=39" in result.stderr


def test_sequence_mode_checks_the_default_init(route: tuple[Path, Path], tmp_path: Path) -> None:
    _, query = route
    result = runner.invoke(app, ["localize", str(query), "--out", str(tmp_path / "s.csv")])
    assert result.exit_code == 1 and "init=100 with exclude_recent=10" in result.stderr
    assert not (tmp_path / "s.csv").exists()


def test_two_queries_with_one_name_are_refused(route: tuple[Path, Path], tmp_path: Path) -> None:
    ref, query = route
    twin = tmp_path / "other" / "query"
    twin.parent.mkdir()
    twin.symlink_to(query, target_is_directory=True)
    result = runner.invoke(app, ["localize", str(query), str(twin), "--map", str(ref), "--out", str(tmp_path / "o")])
    assert result.exit_code == 2 and "same results file" in result.stderr


def test_out_with_a_trailing_slash_names_a_folder(route: tuple[Path, Path], tmp_path: Path) -> None:
    """--out runs.v2/ is a folder, as the guide says, though its name has a suffix: the results
    go into it under their own names (a file runs.v2 was written, and two queries refused); a
    file there is refused before any work."""
    ref, query = route
    folder = tmp_path / "runs.v2"
    ran = runner.invoke(app, ["localize", str(query), "--map", str(ref), "--method", "threshold",
                              "--out", f"{folder}/", "--json"])
    assert ran.exit_code == 0, ran.output
    assert [p.name for p in folder.iterdir()] == ["query-sad-threshold.csv"]
    both = runner.invoke(app, ["localize", str(query), str(ref), "--map", str(ref), "--method", "threshold",
                               "--out", f"{tmp_path / 'both.v2'}/"])
    assert both.exit_code == 0, both.output
    assert sorted(p.name for p in (tmp_path / "both.v2").iterdir()) == ["query-sad-threshold.csv", "ref-sad-threshold.csv"]
    (tmp_path / "taken.csv").write_text("a file\n")
    refused = runner.invoke(app, ["localize", str(query), "--map", str(ref), "--out", f"{tmp_path / 'taken.csv'}/"])
    assert refused.exit_code == 2 and "error: --out: " in refused.stderr and "is a file, not a folder" in refused.stderr
    assert (tmp_path / "taken.csv").read_text() == "a file\n"


@pytest.mark.parametrize("follow", [False, True])
def test_out_without_a_suffix_over_a_file_is_refused(route: tuple[Path, Path], tmp_path: Path, follow: bool) -> None:
    """--out NAME without a suffix names a folder, so a file of that name is refused before any
    work, as one with a trailing slash is (it ended in an error about a lock file inside it)."""
    ref, query = route
    (tmp_path / "taken").write_text("a file\n")
    refused = runner.invoke(app, ["localize", str(query), "--map", str(ref), "--out", str(tmp_path / "taken"),
                                  *(["--follow", "--idle", "0"] if follow else [])])
    assert refused.exit_code == 2 and f"error: --out: {tmp_path / 'taken'} is a file, not a folder" in refused.stderr
    assert (tmp_path / "taken").read_text() == "a file\n"


def test_evaluate_positions_needs_a_radius(route: tuple[Path, Path], tmp_path: Path) -> None:
    ref, query = route
    out = tmp_path / "t.csv"
    assert runner.invoke(app, ["localize", str(query), "--map", str(ref), "--method", "threshold",
                               "--out", str(out)]).exit_code == 0
    for name in ("q.csv", "r.csv"):
        (tmp_path / name).write_text("name,x,y\n" + "".join(f"img{i}.png,{i},0\n" for i in range(40)))
    result = runner.invoke(app, ["evaluate", str(out), "--gt", f"positions:{tmp_path / 'q.csv'}",
                                 "--gt-map", str(tmp_path / "r.csv")])
    assert result.exit_code == 2 and "--radius: positions ground truth needs a radius" in result.stderr
    ok = _json(runner.invoke(app, ["evaluate", str(out), "--gt", f"positions:{tmp_path / 'q.csv'}",
                                   "--gt-map", str(tmp_path / "r.csv"), "--radius", "1.5", "--json"]))["runs"]
    assert ok[0]["with_true_match"] == 40


def test_matrix_ground_truth_picks_a_mat_variable(route: tuple[Path, Path], tmp_path: Path) -> None:
    import scipy.io
    ref, query = route
    out = tmp_path / "t.csv"
    assert runner.invoke(app, ["localize", str(query), "--map", str(ref), "--method", "threshold",
                               "--out", str(out)]).exit_code == 0
    scipy.io.savemat(tmp_path / "gt.mat", {"truth": np.eye(40), "other": np.zeros((40, 40))})
    ambiguous = runner.invoke(app, ["evaluate", str(out), "--gt", f"matrix:{tmp_path / 'gt.mat'}"])
    assert ambiguous.exit_code == 1 and "truth" in ambiguous.stderr and "other" in ambiguous.stderr
    picked = _json(runner.invoke(app, ["evaluate", str(out), "--gt", f"matrix:{tmp_path / 'gt.mat'}:truth",
                                       "--json"]))["runs"]
    assert picked[0]["with_true_match"] == 40 and picked[0]["recall_at_1"] > 0.8


def test_evaluate_draws_the_matrix_and_example_pairs_of_each_run(route: tuple[Path, Path], tmp_path: Path) -> None:
    ref, query = route
    runs = [tmp_path / f"query-{method}.csv" for method in ("online", "threshold")]
    for method, out in zip(("online", "threshold"), runs):
        assert runner.invoke(app, ["localize", str(query), "--map", str(ref), "--method", method,
                                   "--out", str(out)]).exit_code == 0
    report = _json(runner.invoke(app, ["evaluate", *map(str, runs), "--matrix-plot", str(tmp_path / "m.png"),
                                       "--pairs-plot", str(tmp_path / "p.png"), "--json"]))
    names = sorted(Path(f).name for f in report["files"])
    assert names == ["m-query-online.png", "m-query-threshold.png", "p-query-online.png", "p-query-threshold.png"]
    assert all(Path(f).read_bytes()[:4] == b"\x89PNG" for f in report["files"])


def test_figures_of_runs_of_one_file_name_in_two_folders_are_two_files(route: tuple[Path, Path],
                                                                       tmp_path: Path) -> None:
    """Each run's figure is named after its results file with as many folders as tell files of one
    name apart, where both runs' went to one file, the second drawn over the first."""
    ref, query = route
    runs = [tmp_path / folder / "query-sad-online.csv" for folder in ("a", "b")]
    for out, method in zip(runs, ("online", "threshold")):
        out.parent.mkdir()
        assert runner.invoke(app, ["localize", str(query), "--map", str(ref), "--method", method,
                                   "--out", str(out)]).exit_code == 0
    result = runner.invoke(app, ["evaluate", *map(str, runs), "--matrix-plot", str(tmp_path / "m.png"), "--json"])
    files = _json(result)["files"]
    assert sorted(Path(f).name for f in files) == ["m-a-query-sad-online.png", "m-b-query-sad-online.png"]
    assert "replaced" not in result.stderr and all(Path(f).read_bytes()[:4] == b"\x89PNG" for f in files)
    assert Path(files[0]).read_bytes() != Path(files[1]).read_bytes()


def test_a_run_that_measures_itself_is_warned_of(route: tuple[Path, Path], tmp_path: Path) -> None:
    """A query that is the map (loop closure meant, --map left in) and a trained model tested on its
    own training pair run, with one warning each, on stderr and in the --json warnings."""
    ref, query = route
    result = runner.invoke(app, ["localize", str(ref), "--map", f"{ref}/", "--method", "threshold",
                                 "--out", str(tmp_path / "self.csv"), "--json"])
    [warning] = _json(result)["warnings"]
    assert warning.startswith(f"warning: {ref}: the query is the map itself") and warning in result.stderr.replace("warning ", "warning: ")
    args = ["localize", str(query), "--map", str(ref), "--method", "trained", "--train-gt", "aligned",
            "--pairs", "all", "--out", str(tmp_path / "t.csv"), "--json"]
    own = _json(runner.invoke(app, [*args, "--train-query", str(query), "--train-map", str(ref)]))["warnings"]
    assert [w for w in own if "tested on its own training pair" in w] == [
        f"warning: {query}: --method trained is tested on its own training pair (--train-query, --train-map); "
        "its confidences will look better than on another pair"]
    other = _json(runner.invoke(app, [*args, "--train-query", str(ref), "--train-map", str(query)]))["warnings"]
    assert not [w for w in other if w.startswith("warning:")]


def test_describe_list_of_a_cache_folder_that_is_not_there_says_so(tmp_path: Path) -> None:
    """A misspelt --cache listed as an empty cache looked like a cache emptied: a note names it (and
    nothing is made there); a file there is an error."""
    missing = tmp_path / "cahce"
    result = runner.invoke(app, ["describe", "--list", "--cache", str(missing), "--json"])
    assert _json(result)["warnings"] == [f"note: {missing}: no such cache folder; nothing has been described into it"]
    assert not missing.exists()
    (tmp_path / "file").write_text("")
    result = runner.invoke(app, ["describe", "--list", "--cache", str(tmp_path / "file")])
    assert result.exit_code == 2 and result.stderr.strip() == f"error: --cache: {tmp_path / 'file'} is a file, not a cache folder"


@pytest.mark.parametrize("command", [["describe", "--list"], ["describe", "FOLDER"], ["localize", "FOLDER"],
                                     ["vocabulary", "FOLDER"]])
def test_a_cache_option_naming_a_file_is_a_usage_error(command: list[str], tmp_path: Path) -> None:
    """A bad --cache is a bad option value (exit code 2) for every command, also a folder to be made
    inside a file; it was the cache's error (exit code 1) after the folders were listed."""
    (tmp_path / "file").write_text("")
    (tmp_path / "FOLDER").mkdir()
    args = [str(tmp_path / arg) if arg == "FOLDER" else arg for arg in command]
    for cache in (tmp_path / "file", tmp_path / "file" / "sub"):
        result = runner.invoke(app, [*args, "--cache", str(cache)])
        assert result.exit_code == 2, result.output
        assert result.stderr.startswith(f"error: --cache: {tmp_path / 'file'} is a file, not a cache folder")
        assert not list((tmp_path / "FOLDER").iterdir())
    result = runner.invoke(app, args, env={"WILOC_CACHE": str(tmp_path / "file")})  # no --cache typed
    assert result.exit_code == 2 and result.stderr.startswith(f"error: WILOC_CACHE: {tmp_path / 'file'} is a file")


def test_every_comparison_figure_names_its_data_and_ground_truth(route: tuple[Path, Path], tmp_path: Path,
                                                                 titles: dict[str, str]) -> None:
    """docs/evaluation.md: every figure is titled with the query folders' parent, the descriptor
    and the ground truth. The reliability diagram of evaluate and compare was titled with neither,
    though which matches count as right is the ground truth's (and its tolerance's) doing."""
    ref, query = route
    run = tmp_path / "query-online.csv"
    assert runner.invoke(app, ["localize", str(query), "--map", str(ref), "--method", "online",
                               "--out", str(run)]).exit_code == 0
    subject = f"{tmp_path.name}, sad, aligned by name, +-3 frames"
    for command in ("evaluate", "compare"):
        titles.clear()
        result = runner.invoke(app, [command, str(run), "-T", "3", "--pr-plot", str(tmp_path / "pr.png"),
                                     "--calibration-plot", str(tmp_path / "reliability.png")])
        assert result.exit_code == 0, result.output
        assert set(titles) == {"Precision-recall", "Reliability"}
        assert all(subject in title for title in titles.values()), (command, titles)
    titles.clear()  # inside one run: the right and wrong matches are the ground truth's
    assert runner.invoke(app, ["evaluate", str(run), "-T", "3", "--matrix-plot", str(tmp_path / "matrix.png"),
                               "--pairs-plot", str(tmp_path / "pairs.png")]).exit_code == 0
    assert len(titles) == 2 and all("sad, aligned by name, +-3 frames" in title for title in titles.values()), titles
    titles.clear()  # the learned histograms, which no ground truth enters: the data and descriptor
    assert runner.invoke(app, ["compare", str(run), "--model-plot", str(tmp_path / "model.png")]).exit_code == 0
    assert titles == {"Learned model": f"Learned model: online, query ({tmp_path.name}, sad)"}


def test_figures_of_a_live_run_name_its_map_dataset(route: tuple[Path, Path], tmp_path: Path,
                                                    titles: dict[str, str]) -> None:
    """A run saved from Localizer.results() without ``query`` records no query folder: its figures
    are titled with the map's dataset (Figure 1's was '(, sad)', the others' '?, sad')."""
    import wiloc

    ref, query = route
    loc = wiloc.Localizer(ref, descriptor="sad", method="online", seed=0, cache=tmp_path / "cache")
    for image in sorted(query.iterdir())[:8]:
        loc.observe(image)
    run = loc.results().save(tmp_path / "live-online.csv")
    result = runner.invoke(app, ["compare", str(run), "--model-plot", str(tmp_path / "model.png"),
                                 "--threshold-plot", str(tmp_path / "fig5.png")])
    assert result.exit_code == 0, result.output
    assert titles == {"Learned model": f"Learned model: online, live-online.csv ({tmp_path.name}, sad)",
                      "Precision against threshold": f"Precision against threshold: {tmp_path.name}, sad, "
                                                     "aligned by name, +-2 frames"}


@pytest.mark.parametrize("out", [["--out", "seq.csv"], ["--out", "runs/"], []])
def test_localize_says_in_which_folder_its_results_are(out: list[str], route: tuple[Path, Path], tmp_path: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """The closing line names the results' folder as a path to go to: with --out seq.csv it was '.',
    where no --out gave the absolute folder."""
    ref, query = route
    monkeypatch.chdir(tmp_path)
    result = runner.invoke(app, ["localize", str(query), "--map", str(ref), "--method", "threshold", *out])
    assert result.exit_code == 0, result.output
    folder = tmp_path / "runs" if out[1:] == ["runs/"] else tmp_path
    assert f"resultsin{folder};" in "".join(result.stdout.split())


def test_a_followed_run_ends_naming_its_results_file_whole(route: tuple[Path, Path], tmp_path: Path,
                                                           monkeypatch: pytest.MonkeyPatch) -> None:
    ref, query = route
    monkeypatch.chdir(tmp_path)
    result = runner.invoke(app, ["localize", str(query), "--map", str(ref), "--method", "threshold", "--follow",
                                 "--idle", "0.3", "--out", "live.csv"])
    assert result.exit_code == 0, result.output
    assert result.stdout.splitlines()[-1].endswith(f"; results in {tmp_path / 'live.csv'}")


def test_a_followed_runs_lines_keep_one_field_per_column_whatever_the_names(route: tuple[Path, Path],
                                                                           tmp_path: Path) -> None:
    """A tab or line break in a frame's name split its tab-separated line."""
    ref, query = route
    live = tmp_path / "live"
    live.mkdir()
    names = ["tab\there.png", "line\nbreak.png", "back\\slash.png"]
    for name, path in zip(names, sorted(query.iterdir())):
        (live / name).write_bytes(path.read_bytes())
    result = runner.invoke(app, ["localize", str(live), "--map", str(ref), "--method", "threshold", "--follow",
                                 "--idle", "0.3", "--out", str(tmp_path / "live.csv")])
    assert result.exit_code == 0, result.output
    _header, *lines, _end = result.stdout.splitlines()
    assert len(lines) == len(names) and all(len(line.split("\t")) == 5 for line in lines)
    assert sorted(line.split("\t")[0] for line in lines) == sorted(["tab\\there.png", "line\\nbreak.png",
                                                                    "back\\\\slash.png"])


@pytest.mark.parametrize("given", [".", "./", "..", "sub/.."])
def test_a_query_given_as_dot_or_dot_dot_is_named_by_its_folder(given: str, route: tuple[Path, Path],
                                                                 tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """`localize .` wrote "-sad-threshold.csv" (a name read back as an option) and `x/..` one
    named "..-sad-threshold.csv", with the table's and --json's query blank or "..": each is the
    folder's own name, as `describe` and `evaluate` show it."""
    ref, query = route
    (query / "sub").mkdir()
    monkeypatch.chdir(query / "sub" if given == ".." else query)
    ran = runner.invoke(app, ["localize", given, "--map", str(ref), "--method", "threshold", "--out", "runs/", "--json"])
    assert [run["traversal"] for run in _json(ran)["runs"]] == ["query"]
    assert [p.name for p in Path("runs").iterdir()] == ["query-sad-threshold.csv"]
    shown = runner.invoke(app, ["localize", given, "--map", str(ref), "--method", "threshold"], env={"COLUMNS": "200"})
    assert shown.exit_code == 0, shown.output
    assert Path("query-sad-threshold.csv").exists()  # here, as without a dot
    assert "│ query │ threshold" in shown.stdout
