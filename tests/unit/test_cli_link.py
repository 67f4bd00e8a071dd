"""The info/ports/sim/demo commands' failure paths: one line on stderr, a non-zero exit code,
no traceback. (The working paths run against real simulated stations in tests/hil.)"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from uwbcal import cli
from uwbcal.errors import DeviceTimeout, LinkError
from uwbcal.simstations import SimError


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    rc = cli.main(list(argv))
    out, err = capsys.readouterr()
    return rc, out, err


def test_info_wrong_port(capsys: pytest.CaptureFixture[str]) -> None:
    rc, out, err = run(capsys, "info", "--port", "/dev/uwbcal-no-such-port")
    assert rc == LinkError.exit_code
    assert err.count("\n") == 1 and "/dev/uwbcal-no-such-port" in err and "Traceback" not in err


def test_info_silent_device(capsys: pytest.CaptureFixture[str]) -> None:
    rc, out, err = run(capsys, "info", "--port", "loop://", "--timeout", "0.05")
    assert rc == DeviceTimeout.exit_code
    assert err.count("\n") == 1 and "no answer to get_info" in err


def test_ports_json(capsys: pytest.CaptureFixture[str]) -> None:
    rc, out, err = run(capsys, "ports", "--json")
    assert rc == 0
    assert isinstance(json.loads(out)["ports"], list)


@pytest.mark.parametrize("command", [["sim", "--stations", "1"], ["demo"]])
def test_missing_station_binary(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, command: list[str], tmp_path: Path
) -> None:
    monkeypatch.setenv("UWBCAL_STATION", "/nonexistent/uwbcal-station")
    monkeypatch.chdir(tmp_path)               # the demo's default --out is relative: keep it here
    rc, out, err = run(capsys, *command)
    assert rc == SimError.exit_code
    assert "make native" in err and err.count("\n") == 1
    assert list(tmp_path.iterdir()) == []     # refused before anything was written
