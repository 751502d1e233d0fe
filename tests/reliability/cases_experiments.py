"""Bad inputs of experiments: `nerfaug run` settings and datasets, damaged or foreign results folders, `report`."""

from __future__ import annotations

import json
from pathlib import Path

from cases import TINY, case, copy_dataset, edit_json
from harness import Case, copy, make_dataset, write_images


def _run(tmp, bases, *extra, data=None, out=None, says=(), inputs=()) -> Case:
    data = bases.dataset if data is None else data
    out = tmp / "results" if out is None else out
    return Case(["run", "--data", data, "--out", out, *TINY, *extra], [data, *inputs], says=says)


@case
def run_unknown_method(tmp, bases):
    """The issue's example: an unknown method was reported only after training to step 200."""
    return _run(tmp, bases, "--methods", "best-views", says=("best-views",), inputs=[tmp])


@case
def run_method_listed_twice(tmp, bases):
    return _run(tmp, bases, "--methods", "uniform", "uniform", says=("uniform",), inputs=[tmp])


@case
def run_unknown_scene(tmp, bases):
    return Case(["run", "--scenes", "teapot", "--out", tmp / "results", *TINY], [tmp], says=("teapot",))


@case
def run_zero_trials(tmp, bases):
    return _run(tmp, bases, "--trials", "0", says=("--trials", "0"), inputs=[tmp])


@case
def run_negative_trials(tmp, bases):
    return _run(tmp, bases, "--trials", "-1", says=("--trials", "-1"), inputs=[tmp])


@case
def run_workers_beyond_any_machine(tmp, bases):
    return _run(tmp, bases, "--workers", "1099511627776", says=("--workers", "1099511627776"), inputs=[tmp])


@case
def run_steps_below_add_at_step(tmp, bases):
    """The issue's example: views were added at step 20 and never trained on."""
    return _run(tmp, bases, "--steps", "10", says=("--steps", "10"), inputs=[tmp])


@case
def run_zero_resolution(tmp, bases):
    return _run(tmp, bases, "--resolution", "0", says=("--resolution", "0"), inputs=[tmp])


@case
def run_resolution_above_the_source(tmp, bases):
    return _run(tmp, bases, "--resolution", "1000", says=("--resolution", "1000"), inputs=[tmp])


@case
def run_resolution_not_a_whole_factor(tmp, bases):
    return _run(tmp, bases, "--resolution", "3", says=("--resolution", "3"), inputs=[tmp])


@case
def run_negative_seed(tmp, bases):
    return _run(tmp, bases, "--seed", "-1", says=("--seed", "-1"), inputs=[tmp])


@case
def run_zero_workers(tmp, bases):
    return _run(tmp, bases, "--workers", "0", says=("--workers", "0"), inputs=[tmp])


@case
def run_unknown_engine(tmp, bases):
    case = _run(tmp, bases, "--engine", "warp", says=("warp",), inputs=[tmp])
    case.usage = True
    return case


@case
def run_data_missing(tmp, bases):
    return _run(tmp, bases, data=tmp / "nope", says=("nope",), inputs=[tmp])


@case
def run_data_without_test_split(tmp, bases):
    data = copy_dataset(tmp, bases)
    (data / "transforms_test.json").unlink()
    return _run(tmp, bases, data=data, says=("transforms_test.json",))


@case
def run_data_with_too_few_views(tmp, bases):
    data = make_dataset(tmp / "small", train=4, initial=None)
    return _run(tmp, bases, data=data, says=("transforms_train.json", "4"))


@case
def run_data_initial_split_too_small(tmp, bases):
    data = make_dataset(tmp / "small", initial=2)
    return _run(tmp, bases, data=data, says=("transforms_initial.json", "n-initial"))


@case
def run_data_test_split_too_small(tmp, bases):
    data = make_dataset(tmp / "small", test=1)
    return _run(tmp, bases, data=data, says=("transforms_test.json", "n-test"))


@case
def run_data_path_escapes(tmp, bases):
    data = copy_dataset(tmp, bases)
    (tmp / "secret.png").write_bytes((data / "train" / "r_0.png").read_bytes())
    edit_json(data / "transforms_test.json", lambda d: d["frames"][0].update(file_path="../secret"))
    return _run(tmp, bases, data=data, says=("transforms_test.json", "frames[0]"), inputs=[tmp / "secret.png"])


@case
def run_two_scenes_with_one_name(tmp, bases):
    a, b = copy_dataset(tmp / "a", bases, "ds"), copy_dataset(tmp / "b", bases, "ds")
    return Case(["run", "--scenes", a, b, "--out", tmp / "results", *TINY], [a, b], says=("ds",))


@case
def run_folder_shadowing_a_builtin_scene(tmp, bases):
    """A folder ./lego must not silently replace the built-in lego scene."""
    copy(bases.dataset, tmp / "lego")
    return Case(
        ["run", "--scenes", "lego", "--out", tmp / "results", *TINY],
        [tmp / "lego"],
        cwd=tmp,
        says=("lego", "ambiguous"),
    )


@case
def run_out_is_a_file(tmp, bases):
    (tmp / "out.txt").write_text("x")
    return _run(tmp, bases, out=tmp / "out.txt", says=("out.txt",), inputs=[tmp / "out.txt"])


@case
def run_out_is_a_users_folder(tmp, bases):
    (tmp / "mine").mkdir()
    (tmp / "mine" / "thesis.tex").write_text("keep me")
    return _run(tmp, bases, out=tmp / "mine", says=("mine",), inputs=[tmp / "mine"])


def _results(tmp, bases) -> Path:
    return copy(bases.results, tmp / "results")


@case
def results_sweep_json_deleted(tmp, bases):
    """The issue's example: without sweep.json, another --steps deleted every finished run."""
    results = _results(tmp, bases)
    (results / "sweep.json").unlink()
    return _run(tmp, bases, "--steps", "22", out=results, says=("sweep.json", "--force"), inputs=[results])


@case
def results_sweep_json_truncated(tmp, bases):
    results = _results(tmp, bases)
    text = (results / "sweep.json").read_text()
    (results / "sweep.json").write_text(text[:30])
    return _run(tmp, bases, "--steps", "22", out=results, says=("sweep.json", "--force"), inputs=[results])


@case
def results_changed_steps(tmp, bases):
    results = _results(tmp, bases)
    return _run(tmp, bases, "--steps", "22", out=results, says=("steps", "21", "22", "--force"), inputs=[results])


@case
def results_of_another_dataset(tmp, bases):
    """One results folder never mixes runs of two datasets that share a folder name."""
    results = _results(tmp, bases)
    other = make_dataset(tmp / "elsewhere" / bases.dataset.name, train=11)
    return _run(tmp, bases, data=other, out=results, says=(bases.dataset.name, "dataset"), inputs=[results])


@case
def results_run_folder_with_a_users_file(tmp, bases):
    results = _results(tmp, bases)
    folder = next((results / "runs").glob("*/*/*"))
    (folder / "result.json").unlink()
    (folder / "my_notes.txt").write_text("keep me")
    return _run(tmp, bases, out=results, says=(folder.name,), inputs=[results])


@case
def report_on_a_missing_folder(tmp, bases):
    return Case(["report", tmp / "nope"], [tmp], says=("nope",))


@case
def report_on_a_dataset(tmp, bases):
    data = copy_dataset(tmp, bases)
    return Case(["report", data], [data], says=(str(data),))


@case
def run_selection_setting_out_of_range(tmp, bases):
    """Refused while the command line is parsed (its usage text, exit 2), before any work."""
    case = _run(tmp, bases, "--selection.temperature", "0", says=("temperature", "0"), inputs=[tmp])
    case.usage = True
    return case


@case
def run_data_captured_set_too_small_to_keep_test_views_apart(tmp, bases):
    # A nerfstudio folder is a captured set (its test views are kept apart by direction); with 3
    # views there is none to spare.
    data = tmp / "ns"
    copy(bases.dataset / "train", data / "images")
    frames = json.loads((bases.dataset / "transforms_train.json").read_text())["frames"][:3]
    for frame in frames:
        frame["file_path"] = "images/" + Path(frame["file_path"]).name + ".png"
    meta = {"w": 8, "h": 8, "fl_x": 9.0, "fl_y": 9.0, "cx": 4.0, "cy": 4.0, "frames": frames}
    (data / "transforms.json").write_text(json.dumps(meta))
    return _run(tmp, bases, data=data, says=("transforms.json", "too small to keep test views apart"), inputs=[tmp])


@case
def run_data_is_a_capture_session(tmp, bases):
    run = copy(bases.session, tmp / "run")
    return _run(tmp, bases, data=run, says=(str(run),), inputs=[tmp])


@case
def run_out_is_the_dataset(tmp, bases):
    data = copy_dataset(tmp, bases)
    return _run(tmp, bases, data=data, out=data, says=(str(data),))


@case
def results_sweep_json_without_fingerprint(tmp, bases):
    results = _results(tmp, bases)
    (results / "sweep.json").write_text("{}")
    return _run(tmp, bases, out=results, says=("sweep.json", "--force"), inputs=[results])


@case
def results_changed_selection_setting(tmp, bases):
    results = _results(tmp, bases)
    return _run(
        tmp,
        bases,
        "--selection.temperature",
        "2",
        out=results,
        says=("selection.temperature", "1.0", "2.0", "--force"),
        inputs=[results],
    )


@case
def results_changed_engine(tmp, bases):
    results = _results(tmp, bases)
    return _run(tmp, bases, "--engine", "cpu", out=results, says=("engine", "cpu", "--force"), inputs=[results])


@case
def results_changed_resolution(tmp, bases):
    results = _results(tmp, bases)
    return _run(
        tmp, bases, "--resolution", "4", out=results, says=("resolution", "8", "4", "--force"), inputs=[results]
    )


@case
def report_with_sweep_json_corrupt(tmp, bases):
    results = _results(tmp, bases)
    (results / "sweep.json").write_text("{")
    return Case(["report", results], [results], says=("sweep.json",))


@case
def results_of_a_dataset_with_the_same_cameras_and_other_images(tmp, bases):
    """Same transforms files, one image changed: still another dataset, never mixed in."""
    results = _results(tmp, bases)
    other = copy(bases.dataset, tmp / "elsewhere" / bases.dataset.name)
    write_images(other / "test", ["r_1"])
    return _run(
        tmp, bases, data=other, out=results, says=(bases.dataset.name, "different content"), inputs=[results, other]
    )


@case
def run_builtin_scene_above_its_source_size(tmp, bases):
    case = _run(tmp, bases, "--resolution", "8000", says=("--resolution", "8000", "800"), inputs=[tmp])
    case.argv[1:3] = ["--scenes", "lego"]
    return case
