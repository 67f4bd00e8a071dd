"""`uwbcal range --distances ... --moves` on boards: the tag is moved by the user, who is asked
on stderr and answers with Enter; a closed stdin is an error naming the distance. Argument
checks come before any station is opened."""

from __future__ import annotations

import io
from pathlib import Path

import pytest
from uwbcal import cli
from uwbcal.commands.range import parse_distances, placer
from uwbcal.sessions.runner import RunError


def test_board_prompt_waits_for_enter(monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setenv("UWBCAL_SIM_DIR", str(tmp_path))            # no simulated world running
    monkeypatch.setattr("sys.stdin", io.StringIO("\n"))
    place = placer("/dev/ttyACM0", "/dev/ttyACM1", 1, 2)
    place(4.0)
    assert "move the tag (/dev/ttyACM1) to 4 m" in capsys.readouterr().err
    with pytest.raises(RunError, match="at 7 m"):
        place(7.0)                                                  # stdin is now at its end


def test_distances_parsed_and_checked(capsys: pytest.CaptureFixture[str]) -> None:
    assert parse_distances("1,2,4,7") == [1.0, 2.0, 4.0, 7.0]
    with pytest.raises(RunError, match="'x'"):
        parse_distances("1,x")
    assert cli.main(["range", "--ref", "a", "--tag", "b", "--distances", "1,2"]) == 9   # --moves missing
    assert "needs --moves" in capsys.readouterr().err
