"""Bad engine settings and records, each refused in one line naming the setting or field: floats
that are not finite, runs too large for this machine's memory, settings that diverge, settings an
engine does not read, an option that means nothing alone, a sparse start's pool naming a view
twice, and session files of an older format that name an unknown engine or another engine's
settings."""

from __future__ import annotations

import json

from cases import TINY, case, copy_dataset, edit_json, train_on
from cases_capture import _broken_session, _propose, _session
from harness import Case, run_cli

HUGE = "1000000000"


def _train_with(tmp, bases, *options, says) -> Case:
    data = copy_dataset(tmp, bases)
    return Case(train_on(data, tmp, *options).argv, [data, tmp], says=says)


@case
def train_field_learning_rate_infinite(tmp, bases):
    option = "--engine.optimiser.field-lr"
    return _train_with(tmp, bases, option, "inf", says=(f"{option} inf", "finite"))


@case
def train_scene_far_infinite(tmp, bases):
    return _train_with(tmp, bases, "--engine.scene.far", "inf", says=("--engine.scene.far inf", "finite"))


@case
def train_scene_box_infinite(tmp, bases):
    return _train_with(tmp, bases, "--engine.scene.box-half-size", "inf", says=("--engine.scene.box-half-size inf",))


@case
def train_hidden_dim_beyond_this_machines_memory(tmp, bases):
    option = "--engine.field.hidden-dim"
    return _train_with(tmp, bases, option, HUGE, says=(f"{option} {HUGE}", "memory"))


@case
def train_plane_resolution_beyond_this_machines_memory(tmp, bases):
    option = "--engine.field.planes.resolutions"
    return _train_with(tmp, bases, option, "100000", says=(f"{option} 100000", "memory"))


@case
def train_batch_size_beyond_this_machines_memory(tmp, bases):
    option = "--engine.optimiser.batch-size"
    return _train_with(tmp, bases, option, HUGE, says=(f"{option} {HUGE}", "memory"))


@case
def run_batch_size_beyond_this_machines_memory(tmp, bases):
    option = "--engine.optimiser.batch-size"
    argv = ["run", "--data", bases.dataset, "--out", tmp / "results", *TINY, option, HUGE]
    return Case(argv, [tmp], says=(f"{option} {HUGE}", "memory"))


@case
def train_a_learning_rate_that_diverges(tmp, bases):
    """Finite, so accepted, but the loss is NaN from the second step: the setting's fault, and no
    session that can never train is left behind."""
    data = copy_dataset(tmp, bases)
    argv = ["train", data, "--out", tmp / "run", "--engine", "test", "--steps", "5", "--device", "cpu"]
    option = "--engine.optimiser.field-lr"
    return Case([*argv, option, "1e30"], [data, tmp], says=("diverged", option))


@case
def train_a_hash_grid_setting_on_a_k_planes_engine(tmp, bases):
    option = "--engine.field.hash.levels"
    return _train_with(tmp, bases, option, "8", says=(f"{option} 8", "not used by this engine"))


@case
def train_a_layout_without_a_sparse_start(tmp, bases):
    return _train_with(tmp, bases, "--layout", "2", says=("--layout 2", "--initial"))


@case
def run_an_unknown_engine(tmp, bases):
    data = copy_dataset(tmp, bases)
    argv = ["run", "--data", data, "--out", tmp / "results", *TINY, "--engine", "nope"]
    return Case(argv, [data, tmp], says=("--engine 'nope'", "nerfacto-cpu"))


@case
def run_an_engine_by_an_earlier_records_flat_name(tmp, bases):
    """The flat form is read from records only; on the command line the refusal gives the options."""
    data = copy_dataset(tmp, bases)
    argv = ["run", "--data", data, "--out", tmp / "results", *TINY, "--engine", "test+lr=0.005"]
    return Case(argv, [data, tmp], says=("--engine 'test+lr=0.005'", "--engine test --engine.optimiser.lr 0.005"))


@case
def train_an_unknown_engine(tmp, bases):
    return _train_with(tmp, bases, "--engine", "nope", says=("--engine", "'nope'"))


@case
def train_an_engine_setting_on_a_session_of_another_engine(tmp, bases):
    """The session's engine is `test`; the refusal names the engine asked for as the session's
    engine with the setting, never the default engine the user did not give."""
    run = _session(tmp, bases)
    argv = ["train", run, "--steps", "10", "--device", "cpu", "--engine.field.hidden-dim", "32"]
    return Case(argv, [run], says=("--engine test --engine.field.hidden-dim 32", "(the session's: test)"))


@case
def propose_from_a_pool_naming_a_view_twice(tmp, bases):
    run = tmp / "sparse"
    argv = ["train", bases.dataset, "--out", run, "--engine", "test", "--steps", "1", "--initial", "3"]
    outcome = run_cli([*argv, "--device", "cpu"])
    assert outcome.code == 0, outcome.err

    def twice(pool):
        pool["frames"][1]["file_path"] = pool["frames"][0]["file_path"]

    edit_json(run / "pool.json", twice)
    name = json.loads((run / "pool.json").read_text())["frames"][0]["file_path"].rsplit("/", 1)[-1]
    return Case(_propose(run, tmp), [run], says=("pool.json", "frames[1].file_path", name, "twice"))


@case
def session_file_whose_format_is_true(tmp, bases):
    return _broken_session(tmp, bases, lambda data: data.update(format=True), "'format'", "True")


def _format_1(data: dict, preset: str) -> None:
    """A format-1 record: the engine's name under "preset", its settings under "engine"."""
    data.update(format=1, preset=preset, engine=data.pop("engine_config"))


@case
def session_file_of_format_1_naming_an_unknown_engine(tmp, bases):
    return _broken_session(tmp, bases, lambda data: _format_1(data, "bogus"), "'engine'", "bogus")


@case
def session_file_of_format_1_naming_another_engine_than_its_settings(tmp, bases):
    return _broken_session(tmp, bases, lambda data: _format_1(data, "cpu"), "'engine'", "'engine_config'", "'cpu'")


@case
def train_a_blender_camera_1e5_scene_radii_away(tmp, bases):
    """Blender listings give no scene scale: the scene is the one the cameras frame."""
    data = copy_dataset(tmp, bases)

    def far(listing):
        matrix = listing["frames"][3]["transform_matrix"]
        for row in matrix[:3]:
            row[3] *= 1e5

    edit_json(data / "transforms_train.json", far)
    return Case(
        train_on(data, tmp).argv,
        [data, tmp],
        says=("transforms_train.json", "frames[3].transform_matrix", "scene radii"),
    )
