"""Every uwbcal command (and every `table` subcommand) takes --json, and an error in --json mode
is one JSON object {"error", "code"} on stdout with the command's exit code."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest
from uwbcal import cli


def _subparsers(p: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for a in p._actions:
        if isinstance(a, argparse._SubParsersAction):
            return dict(a.choices)
    return {}


def test_every_command_takes_json() -> None:
    missing = []
    for name, sp in _subparsers(cli.build_parser()).items():
        nested = _subparsers(sp)
        for sub_name, target in (nested.items() if nested else [(None, sp)]):
            opts = {o for a in target._actions for o in a.option_strings}
            if "--json" not in opts:
                missing.append(f"{name} {sub_name or ''}".strip())
    assert not missing, f"no --json on: {missing}"


@pytest.mark.parametrize("argv, code", [
    (["table", "push", "--port", "/nonexistent/port", "t.json", "--json"], 6),     # no table file
    (["analyze", "twr", "/nonexistent.db", "--json"], 5),
    (["range", "--json"], 9),                                                      # no ports
    (["calibrate", "--steps", "x", "--json"], 2),                                  # usage error
])
def test_errors_are_json_with_the_exit_code(argv: list[str], code: int, tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str],
                                            monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    assert cli.main(argv) == code
    doc = json.loads(capsys.readouterr().out)
    assert doc["code"] == code and doc["error"]
