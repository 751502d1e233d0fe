"""`nerfaug --help` and each command's: the values that will be used (a preset's, not "None"),
readable metavars, every command listed, text wrapped by the help rather than broken mid-sentence;
and `study`'s `--selection.*` options, which leave the study's fingerprint alone at their defaults."""

import re

import pytest

from nerfaug.cli import main, reflow
from nerfaug.experiment.store import fingerprint


def help_text(argv: list[str], capsys, monkeypatch) -> str:
    monkeypatch.setenv("COLUMNS", "400")  # one line per option's help: a hard break shows as a second line
    with pytest.raises(SystemExit) as done:
        main([*argv, "--help"])
    assert done.value.code == 0
    return capsys.readouterr().out


def test_run_help_shows_the_presets_values_not_none(capsys, monkeypatch):
    text = help_text(["run"], capsys, monkeypatch)
    options = text.split("selection options")[0]  # a selection option's None is its real default
    assert "(default: None)" not in options and "{None}" not in options
    assert "--scenes SCENE [SCENE ...]" in text and "--trials INT" in text
    steps = re.compile(r"training steps per run\. \(default: (\d+)\)")
    assert steps.search(text).group(1) == "800"  # the default preset's, quick
    paper = help_text(["run", "--preset", "paper"], capsys, monkeypatch)
    assert steps.search(paper).group(1) == "10000"
    assert "(default: paper)" in paper and "(default: lego chair materials)" in paper


def test_top_level_help_lists_every_command(capsys, monkeypatch):
    from nerfaug.cli import COMMANDS

    text = help_text([], capsys, monkeypatch)
    usage = re.search(r"usage: nerfaug \[-h\] \{([^}]*)\}", text)
    assert usage is not None, text
    listed = set(usage.group(1).split(","))
    capture = {"train", "propose", "add", "export", "eval", "render-proposals", "serve", "uncertainty"}
    assert {"scene", "run", "report", "methods", "study", *capture} <= listed
    assert listed == set(COMMANDS)
    # The examples above the usage line show every command too (as `nerfaug NAME ...`).
    shown = {line.split()[1] for line in text.split("usage:")[0].splitlines() if line.startswith("nerfaug ")}
    assert shown == set(COMMANDS), set(COMMANDS) ^ shown


def test_study_help_lists_selection_options_and_no_none_defaults(capsys, monkeypatch):
    text = help_text(["study"], capsys, monkeypatch)
    assert "--selection.sharpness" in text
    options = text.split("selection options")[0]
    assert "(default: None)" not in options and "{None}" not in options


def every_command(capsys, monkeypatch) -> dict[str, str]:
    """Each command's help, found by walking the `{a,b,...}` subcommand lists from the top."""
    helps, todo = {}, [[]]
    while todo:
        argv = todo.pop()
        text = help_text(argv, capsys, monkeypatch)
        helps[" ".join(argv)] = text
        usage = re.search(r"usage: nerfaug[\w -]* \[-h\] \{([^}]*)\}", text)  # a command's subcommands
        if usage is not None:
            todo += [[*argv, command] for command in usage.group(1).split(",")]
    return helps


def test_no_command_help_shows_none_for_a_default(capsys, monkeypatch):
    helps = every_command(capsys, monkeypatch)
    assert {"", "scene", "scene render", "propose", "train", "serve", "eval", "uncertainty"} <= set(helps)
    for command, text in helps.items():
        assert "(default: None)" not in text and "{None}" not in text, command
    propose = helps["propose"]
    assert "--selection.metric M11 M12 M13 M21 M22 M23 M31 M32 M33" in propose
    assert "(default: the identity)" in propose and "(default: the largest score)" in propose
    assert "--elevation LOW HIGH" in propose and "(default: any)" in propose
    monkeypatch.setenv("COLUMNS", "80")  # one column of option groups: a help's words in order
    with pytest.raises(SystemExit):
        main(["serve", "--help"])
    serve = " ".join(capsys.readouterr().out.replace("│", " ").split())
    assert "(default: the NERFAUG_TOKEN environment variable, if set)" in serve


def test_the_metric_is_nine_numbers_row_by_row_on_the_command_line():
    import tyro

    from nerfaug.selection.config import SelectionConfig

    given = tyro.cli(SelectionConfig, args=["--metric", "2", "0.5", "0", "0.5", "1", "0", "0", "0", "3"])
    assert given.metric == [[2.0, 0.5, 0.0], [0.5, 1.0, 0.0], [0.0, 0.0, 3.0]]
    assert tyro.cli(SelectionConfig, args=[]).metric is None


def test_option_help_is_one_line_in_a_wide_terminal(capsys, monkeypatch):
    text = help_text(["run"], capsys, monkeypatch)
    body = [line.strip("│ ").rstrip() for line in text.splitlines() if line.startswith("│")]
    # Each option is its flag line followed by exactly one help line (none broken by the docstring).
    flags = [i for i, line in enumerate(body) if line.startswith("--") or line.startswith("-h")]
    for here, after in zip(flags, flags[1:]):
        if "selection options" in "".join(body[here:after]) or "──" in "".join(body[here:after]):
            continue  # the panel's end and the next panel's heading
        assert after - here == 2, body[here:after]


def test_reflow_joins_paragraphs_and_argument_descriptions_but_keeps_headings():
    doc = """Summary line.

    A paragraph over
    two lines.

    Args:
        first: a description over
            two lines.
        second: one line.
    """
    assert reflow(doc).splitlines() == [
        "Summary line.",
        "",
        "A paragraph over two lines.",
        "",
        "Args:",
        "    first: a description over two lines.",
        "    second: one line.",
    ]


def test_study_selection_options_apply_and_leave_the_fingerprint_alone_at_their_defaults(monkeypatch, tmp_path):
    import nerfaug.cli.study_work as study_cli
    import nerfaug.experiment.study as study_module
    import nerfaug.report.study_page as study_page

    planned = []

    def make_plan(spec, command, **_):
        config = study_module.STUDY_PRESETS.choose(spec.preset, resolution=spec.resolution, device="cpu")
        plan = study_module.StudyPlan(
            spec.out, config, ["test"], scenes=["lego"], datasets={"lego": "lego"}, command=command
        )
        planned.append(plan)
        return plan

    monkeypatch.setattr(study_module, "make_plan", make_plan)
    monkeypatch.setattr(study_module, "run_study", lambda plan, **kw: {})
    monkeypatch.setattr(study_cli, "record_table", lambda out, path, previous: {"runs": []})
    monkeypatch.setattr(study_page, "write_study", lambda out, recorded, plan="auto", one_shot=None: [])
    base = ["study", "--out", str(tmp_path / "s"), "--preset", "tiny", "--workers", "1"]
    main(base)
    main([*base, "--selection.temperature", "1.0", "--selection.entropy-resolution", "40"])
    main([*base, "--selection.sharpness", "0.5"])
    default, same, sharper = (fingerprint(p.config.fingerprinted()) for p in planned)
    untouched = study_module.STUDY_PRESETS.choose("tiny", resolution=100, device="cpu")
    assert default == same == fingerprint(untouched.fingerprinted())
    assert sharper != default and planned[2].config.selection.sharpness == 0.5
    assert planned[2].command[-2:] == ["--selection.sharpness", "0.5"]
    assert not any(word.startswith("--selection") for word in planned[1].command)


# The code's words and the project's history, which belong in docs (docs/methods.md), not in --help.
INTERNAL = (
    "ray_entropy",
    "combined_uncertainty",
    "H_train",
    "H_cand",
    "Rademacher",
    "the 15 of",
    "BENCHMARKS.md",
    "benchmarks/",
    "nerfaug.selection",
    "nerfaug.uncertainty",
    "Spearman",
    "(default: )",
)


def test_every_help_speaks_the_users_words_and_each_option_name_means_one_thing(capsys, monkeypatch):
    helps = every_command(capsys, monkeypatch)
    for command, text in helps.items():
        for word in INTERNAL:
            assert word not in text, (command, word)
    # --engine is a NeRF engine preset wherever it appears, with the same names.
    engines = {c: re.search(r"--engine \{([^}]*)\}", t) for c, t in helps.items() if "--engine {" in t}
    assert {"run", "train"} <= set(engines)
    assert len({m.group(1) for m in engines.values()}) == 1
    # --preset is an experiment's protocol (run, study), never an engine preset.
    assert "--preset" not in helps["train"]
    assert "quick" in re.search(r"--preset \{([^}]*)\}", helps["run"]).group(1)
    # The angle convention of every output: elevation.
    assert "elevation" in helps["propose"] and "azimuth, polar" not in helps["propose"]


# Every command, as its words on the command line (`nerfaug scene render`: two).
EVERY_COMMAND = [
    "run",
    "study",
    "report",
    "methods",
    "engines",
    "propose",
    "export",
    "eval",
    "render-proposals",
    "uncertainty",
    "train",
    "add",
    "serve",
    "view",
    "scene render",
    "scene prepare",
]


def test_the_light_help_test_names_every_command():
    from nerfaug.cli import COMMANDS

    assert {command.split()[0] for command in EVERY_COMMAND} == set(COMMANDS)


def test_exports_format_names_are_the_registered_formats():
    """`nerfaug export --format` names the formats without importing their registry (torch)."""
    import typing

    from nerfaug.cli.session import EXCHANGE_FORMAT, FormatName
    from nerfaug.data import formats

    assert typing.get_args(FormatName) == tuple(formats.FORMATS)
    assert EXCHANGE_FORMAT == formats.EXCHANGE_FORMAT


@pytest.mark.parametrize("command", EVERY_COMMAND)
def test_a_commands_help_loads_no_torch(command):
    """`nerfaug COMMAND --help` parses its options before anything heavy is imported: torch alone
    takes seconds to import (BENCHMARKS.md, "`--help` start-up"), numpy, FastAPI and matplotlib
    a good part of one; each command's options are light, its work is imported when it runs."""
    done = help_in_a_fresh_process(
        command.split(), "sorted(m for m in ('torch', 'numpy', 'fastapi', 'matplotlib') if m in sys.modules)"
    )
    assert f"usage: nerfaug {command}" in done.stdout
    assert done.stdout.strip().splitlines()[-1] == "[]", command


def test_trains_old_preset_option_names_its_new_spelling(capsys):
    with pytest.raises(SystemExit) as refused:
        main(["train", "data", "--out", "run", "--preset=test"])
    assert refused.value.code == 2
    error = capsys.readouterr().err.strip()
    assert error.startswith("nerfaug: --preset: `nerfaug train` takes the NeRF engine as --engine")


def help_in_a_fresh_process(argv: list[str], loaded: str):
    """`nerfaug ARGV --help` in a new Python process, which then prints the expression `loaded`
    (over `sys.modules`) as its last line; the finished process (exit 0 checked)."""
    import subprocess
    import sys

    probe = (
        "import sys\nfrom nerfaug.cli import main\n"
        f"try:\n    main([*{argv!r}, '--help'])\nexcept SystemExit:\n    pass\n"
        f"print({loaded})"
    )
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return done


@pytest.mark.parametrize("argv", [[], ["scene"], ["scene", "render"], ["scene", "prepare"]])
def test_the_overview_and_the_scene_commands_help_load_no_command_and_no_torch(argv):
    """`nerfaug --help` lists the commands without importing them (it took seconds, loading every
    command's options, torch among them); `nerfaug scene render --help` reads its options alone."""
    done = help_in_a_fresh_process(
        argv, "sorted(m for m in sys.modules if m == 'torch' or m.startswith(('nerfaug.cli.run', 'nerfaug.cli.s')))"
    )
    loaded = done.stdout.strip().splitlines()[-1]
    assert loaded == ("['nerfaug.cli.scene']" if argv else "[]"), loaded


def test_a_mistyped_command_is_answered_with_the_closest_one(capsys):
    with pytest.raises(SystemExit) as refused:
        main(["trian", "--help"])
    assert refused.value.code == 2
    error = capsys.readouterr().err.strip()
    assert error.startswith("nerfaug: unknown command 'trian'; did you mean 'train'? choose one of: scene, run,")


def test_an_engine_preset_is_offered_without_none_and_a_typo_gets_the_closest_name(capsys):
    with pytest.raises(SystemExit) as refused:
        main(["train", "data", "--out", "run", "--engine", "papr"])
    assert refused.value.code == 2
    error = " ".join(capsys.readouterr().err.replace("│", " ").split())
    assert "'None'" not in error and "None," not in error
    assert "unknown engine preset 'papr'; did you mean 'paper'? choose one of: paper, cpu, nerfacto-cpu, test" in error


ENGINE_HELP = "--engine.GROUP.SETTING VALUE (e.g. --engine.field.hidden-dim 32); `nerfaug engines` lists them."


@pytest.mark.parametrize("command", ["train", "run", "study", "serve"])
def test_an_engine_commands_help_names_the_engine_settings_in_one_line_and_lists_none(capsys, monkeypatch, command):
    text = help_text([command], capsys, monkeypatch)
    assert ENGINE_HELP in text, text
    options = [line for line in text.splitlines() if line.strip("│ ").startswith("--engine.")]
    assert options == [], options
    if command in ("train", "run"):
        assert re.search(r"--engine \{", text)  # the engine's name stays an option of its own


def engines_text(capsys, monkeypatch) -> str:
    monkeypatch.setenv("COLUMNS", "400")
    main(["engines"])
    return capsys.readouterr().out


def test_nerfaug_engines_lists_every_engine_and_every_setting_with_its_help(capsys, monkeypatch):
    from nerfaug.nerf.config import FLAT_NAMES, PRESETS

    text = engines_text(capsys, monkeypatch)
    assert all(name in text.splitlines()[0] for name in PRESETS)
    listed = set(re.findall(r"(--engine\.[\w.-]+) ", text))
    assert listed == {"--engine." + ".".join(path).replace("_", "-") for path in FLAT_NAMES.values()}
    assert "--engine.field.hidden-dim INT" in text and "density MLP width" in text


def test_every_setting_nerfaug_engines_lists_is_accepted_wherever_it_stands(capsys, monkeypatch):
    """Each listed setting, given the paper engine's own value, reads back as that value, with the
    command's other arguments before, between and after the settings left to the command."""
    from nerfaug.cli.engine_options import engine_settings_given, split_engine_options
    from nerfaug.nerf.config import FLAT_NAMES, PRESETS, NerfConfig, preset_value

    paper, words, others, expected = PRESETS["paper"], [], [], {}
    for at, path in enumerate(FLAT_NAMES.values()):
        value = preset_value(paper, path)  # the parts paper does not use: at their defaults
        many = isinstance(value, tuple)
        words += ["--engine." + ".".join(path).replace("_", "-"), *(str(v) for v in (value if many else [value]))]
        *groups, leaf = path
        group = expected
        for step in groups:
            group = group.setdefault(step, {})
        group[leaf] = value  # nested, by the names the options give
        # After it, now and then, an option of the command, or a positional word (not after a list,
        # which takes every word up to the next option, as the parser always has).
        after = ["--steps", str(at)] if at % 3 == 0 else [f"WORD{at}"] if at % 3 == 1 and not many else []
        words, others = words + after, others + after
    settings, rest = split_engine_options(["DATA", *words])
    assert rest == ["DATA", *others]
    assert engine_settings_given(settings, "nerfaug train") == expected
    assert NerfConfig.from_dict(expected) == paper  # read as a record: the parts paper does not use left out


def test_split_engine_options_takes_one_value_or_a_list_and_leaves_the_rest_in_order():
    from nerfaug.cli.engine_options import split_engine_options

    args = ["--engine.field.hidden-dim=32", "DATA", "--engine.optimiser.lr", "-0.5", "--engine", "paper"]
    assert split_engine_options(args) == (
        ["--engine.field.hidden-dim=32", "--engine.optimiser.lr", "-0.5"],
        ["DATA", "--engine", "paper"],
    )
    listed = ["--engine.sampler.proposal.samples", "64", "32", "--out", "RUN"]
    assert split_engine_options(listed) == (listed[:3], ["--out", "RUN"])
    assert split_engine_options(["--engine.no.such", "3", "DATA"]) == (["--engine.no.such", "3"], ["DATA"])
    after = ["--", "--engine.field.hidden-dim", "3"]  # positional words
    assert split_engine_options(after) == ([], after)


@pytest.mark.parametrize("command", ["train", "run", "study", "serve"])
def test_an_engine_commands_help_builds_neither_the_settings_form_nor_a_validator(command):
    """What made `--help` slow, kept out of it: the engine settings' form (its help reads every
    setting's docstring) and pydantic's validator of the engine; each is built when a command runs."""
    done = help_in_a_fresh_process(
        [command],
        "(sys.modules.get('nerfaug.nerf.engine_form') is not None, "
        "__import__('nerfaug.schema').schema.adapter.cache_info().currsize)",
    )
    assert done.stdout.strip().splitlines()[-1] == "(False, 0)", done.stdout[-300:]
