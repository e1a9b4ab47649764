"""What every command shares: `--version`, help without `<bool>`, the extra a command needs,
one rule for `--threads`, one WIDTHxHEIGHT parser."""

from __future__ import annotations

import subprocess
import sys
from importlib import import_module

import pytest
from typer.testing import CliRunner

import rtdenoise

COMMANDS = ("export", "run", "train", "render", "bench")
runner = CliRunner()


def app_of(command: str):
    return import_module(f"rtdenoise.cli.{command}").app


@pytest.mark.parametrize("command", COMMANDS)
def test_version_on_every_command(command):
    res = runner.invoke(app_of(command), ["--version"])
    assert res.exit_code == 0, res.output
    assert res.output.startswith(f"rtdenoise {rtdenoise.__version__} (Python ")
    assert "onnxruntime " in res.output and res.output.count("\n") == 1


@pytest.mark.parametrize(
    "argv",
    [["export"], ["run"], ["train"], ["render"], ["bench"], ["bench", "model"], ["bench", "op"]],
)
def test_help_shows_no_bool_type_on_flags(argv):
    command, *sub = argv
    res = runner.invoke(app_of(command), [*sub, "--help"], terminal_width=120)
    assert res.exit_code == 0, res.output
    assert "--help" in res.output and "<bool>" not in res.output


def test_train_help_lists_the_families(monkeypatch):
    """Found from the entry points (no torch import), and the same as the registry's."""
    from rtdenoise.cli.common import family_names
    from rtdenoise.models.registry import families

    assert family_names() == families()
    monkeypatch.setenv("COLUMNS", "250")
    res = runner.invoke(app_of("train"), ["--help"])
    assert f"Model family: {', '.join(families())}, or one of --family-module." in res.output


@pytest.mark.parametrize(
    "command, argv, extra",
    [
        ("export", ["demo:afn", "-o", "x.onnx"], "export"),
        ("train", ["seq", "-o", "x.pt"], "train"),
        ("bench", ["model", "demo:afn", "--size", "16x16"], "bench"),
    ],
)
def test_missing_extra_says_what_to_install(tmp_path, command, argv, extra):
    """torch blocked, as in a base install: one line naming the extra, exit 2."""
    code = (
        "import sys; sys.modules['torch'] = None; "
        f"from rtdenoise.cli.{command} import main; sys.argv[1:] = {argv!r}; main()"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=tmp_path
    )
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr == (
        f"error: no module named 'torch': this command needs the {extra} extra: "
        f"pip install 'rtdenoise[{extra}]'\n"
    )


def test_render_without_mitsuba_names_the_data_extra(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "mitsuba", None)
    res = runner.invoke(app_of("render"), [str(tmp_path / "out")])
    assert res.exit_code == 2
    assert "pip install 'rtdenoise[data]'" in res.output  # not eaten as rich markup


@pytest.mark.parametrize("argv", [["run", "x", "-o", "o"], ["bench", "model", "afn"]])
def test_threads_zero_is_refused_everywhere(argv):
    command, *rest = argv
    res = runner.invoke(app_of(command), [*rest, "--threads", "0"])
    assert res.exit_code == 2 and "'--threads'" in res.output
    assert "greater than or equal to 1" in res.output


def test_bench_and_render_parse_width_x_height():
    from rtdenoise.cli.common import parse_size
    from rtdenoise.runtime.errors import InputError

    assert parse_size("1280x720") == (1280, 720) and parse_size(" 64X32 ") == (64, 32)
    for bad in ("1280", "0x10", "axb", "10x-1"):
        with pytest.raises(InputError, match="expected WIDTHxHEIGHT"):
            parse_size(bad)


def _help_texts(command, path=()):
    """(where, text) of a click command's help and its parameters' help, subcommands too."""
    yield path, command.help or ""
    for param in command.params:
        yield (*path, param.name), getattr(param, "help", None) or ""
    for name, sub in getattr(command, "commands", {}).items():
        yield from _help_texts(sub, (*path, name))


@pytest.mark.parametrize("command", COMMANDS)
def test_help_keeps_bracketed_words(command):
    """Rich reads `[bench]` in a help text as a style tag and prints nothing in its place
    ("Needs the  extra"); help that is rendered as markup must not hold one."""
    import re

    import typer

    app = app_of(command)
    if app.rich_markup_mode is None:
        return
    eaten = [
        (where, tag)
        for where, text in _help_texts(typer.main.get_command(app), (command,))
        for tag in re.findall(r"(?<!\\)\[[A-Za-z_][\w.-]*\]", text)
    ]
    assert eaten == []


@pytest.mark.parametrize(
    "argv",
    [["export"], ["run"], ["train"], ["render"], ["bench"], ["bench", "model"], ["bench", "op"],
     ["bench", "compare"], ["bench", "stages"]],
)  # fmt: skip
def test_short_help_on_every_command(argv):
    """`-h` is `--help` everywhere, subcommands included: the same text."""
    command, *sub = argv
    short = runner.invoke(app_of(command), [*sub, "-h"], terminal_width=120)
    long = runner.invoke(app_of(command), [*sub, "--help"], terminal_width=120)
    assert short.exit_code == 0, short.output
    assert short.output == long.output and "Usage:" in short.output
