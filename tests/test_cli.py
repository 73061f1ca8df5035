"""The command line's contract: exit codes that tell bad input from a bug, one line for bad input, a traceback for a
bug."""
from __future__ import annotations

import argparse

import pytest

from circcal import cli
from circcal.errors import EXIT_BAD_INPUT, EXIT_INTERNAL_ERROR, InputError


def _with_command(monkeypatch, fn) -> None:
    """Replace the parser so that the command ``x`` runs ``fn``."""
    def build() -> argparse.ArgumentParser:
        parser = argparse.ArgumentParser(prog="circcal")
        sub = parser.add_subparsers(dest="command")
        sub.add_parser("x").set_defaults(func=fn)
        return parser

    monkeypatch.setattr(cli, "build_parser", build)


def test_bad_input_is_one_line_and_exit_2(monkeypatch, capsys):
    def bad(args):
        raise InputError("camera file model.json: fx must be a finite number, got True")

    _with_command(monkeypatch, bad)
    assert cli.main(["x"]) == EXIT_BAD_INPUT == 2
    err = capsys.readouterr().err
    assert err.strip() == "circcal x: error: camera file model.json: fx must be a finite number, got True"


def test_a_missing_file_is_bad_input(monkeypatch, capsys):
    def missing(args):
        open("/nonexistent/dir/file.json")

    _with_command(monkeypatch, missing)
    assert cli.main(["x"]) == EXIT_BAD_INPUT
    assert "/nonexistent/dir/file.json: No such file or directory" in capsys.readouterr().err


@pytest.mark.parametrize("exc", [RuntimeError("boom"), ValueError("an internal shape mismatch"), KeyError("k")])
def test_a_bug_keeps_its_traceback_and_exits_70(monkeypatch, capsys, exc):
    """A ValueError from inside circcal is a bug, not bad input: only InputError (and file errors) mean bad input."""
    def buggy(args):
        raise exc

    _with_command(monkeypatch, buggy)
    assert cli.main(["x"]) == EXIT_INTERNAL_ERROR == 70
    err = capsys.readouterr().err
    assert "Traceback (most recent call last)" in err and "in buggy" in err and "internal error" in err


def test_every_command_is_registered():
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    assert set(sub.choices) == set(cli.COMMANDS)
