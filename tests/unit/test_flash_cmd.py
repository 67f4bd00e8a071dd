"""`uwbcal flash`: command construction (--dry-run) and its one-line errors. No probe needed:
fake tools on a private PATH stand for openocd, st-flash and pyocd."""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path

import pytest
from uwbcal.cli import main
from uwbcal.commands import flash


def make_repo(root: Path, suffixes: tuple[str, ...] = (".elf", ".bin")) -> Path:
    """A checkout-shaped directory with the board port marker and the given images."""
    (root / "firmware/boards/evk1000").mkdir(parents=True)
    (root / "firmware/boards/evk1000/board.mk").write_text("# marker\n")
    (root / "build/evk1000").mkdir(parents=True)
    for suffix in suffixes:
        (root / f"build/evk1000/uwbcal-evk1000{suffix}").write_bytes(b"\x00" * 16)
    return root


def fake_tools(bindir: Path, names: tuple[str, ...], exit_code: int = 0) -> None:
    """Executables that record their argv and exit with ``exit_code``."""
    bindir.mkdir(parents=True, exist_ok=True)
    for name in names:
        tool = bindir / name
        tool.write_text(f'#!/bin/sh\necho "$0 $*" >> "{bindir}/calls"\nexit {exit_code}\n')
        tool.chmod(tool.stat().st_mode | stat.S_IEXEC)


@pytest.fixture
def repo(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    root = make_repo(tmp_path / "repo")
    monkeypatch.chdir(root)
    monkeypatch.setenv("PATH", str(tmp_path / "bin"))
    (tmp_path / "bin").mkdir()
    return root


def test_openocd_elf_command() -> None:
    cmd = flash.build_command("openocd", Path("b/x.elf"))
    assert cmd == [
        "openocd", "-f", "interface/stlink.cfg", "-f", "target/stm32f1x.cfg",
        "-c", "program b/x.elf verify reset exit",
    ]


def test_openocd_bin_needs_address() -> None:
    cmd = flash.build_command("openocd", Path("b/x.bin"))
    assert cmd[-1] == "program b/x.bin 0x08000000 verify reset exit"


def test_st_flash_uses_bin_beside_elf(tmp_path: Path) -> None:
    root = make_repo(tmp_path)
    elf = root / "build/evk1000/uwbcal-evk1000.elf"
    cmd = flash.build_command("st-flash", elf)
    assert cmd == ["st-flash", "--reset", "write", str(elf.with_suffix(".bin")), "0x08000000"]


def test_st_flash_without_bin_is_an_error(tmp_path: Path) -> None:
    root = make_repo(tmp_path, suffixes=(".elf",))
    with pytest.raises(flash.FlashError, match="needs a .bin"):
        flash.build_command("st-flash", root / "build/evk1000/uwbcal-evk1000.elf")


def test_pyocd_bin_gets_base_address() -> None:
    cmd = flash.build_command("pyocd", Path("x.bin"))
    assert cmd == ["pyocd", "flash", "--target", "stm32f103rc", "--base-address", "0x08000000", "x.bin"]


def test_auto_prefers_openocd_then_st_flash_then_pyocd() -> None:
    assert flash.pick_tool("auto", lambda n: "/x" if n in ("st-flash", "pyocd") else None) == "st-flash"
    assert flash.pick_tool("auto", lambda n: "/x") == "openocd"
    assert flash.pick_tool("auto", lambda n: "/x" if n == "pyocd" else None) == "pyocd"


def test_dry_run_prints_exact_command_and_runs_nothing(
    repo: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bindir = Path(os.environ["PATH"])
    fake_tools(bindir, ("st-flash",))
    assert main(["flash", "--dry-run"]) == 0
    out = capsys.readouterr().out.strip()
    assert out == f"st-flash --reset write {repo}/build/evk1000/uwbcal-evk1000.bin 0x08000000"
    assert not (bindir / "calls").exists()


def test_dry_run_json(repo: Path, capsys: pytest.CaptureFixture[str]) -> None:
    fake_tools(Path(os.environ["PATH"]), ("openocd",))
    assert main(["flash", "--dry-run", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["tool"] == "openocd" and doc["dry_run"] is True and doc["flashed"] is False
    assert doc["image"].endswith("uwbcal-evk1000.elf")
    assert doc["command"][:2] == ["openocd", "-f"]


def test_dry_run_with_named_tool_not_installed_still_shows_command(
    repo: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["flash", "--dry-run", "--tool", "pyocd"]) == 0
    assert capsys.readouterr().out.startswith("pyocd flash --target stm32f103rc ")


def test_runs_the_tool(repo: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bindir = Path(os.environ["PATH"])
    fake_tools(bindir, ("openocd",))
    assert main(["flash"]) == 0
    calls = (bindir / "calls").read_text()
    assert "interface/stlink.cfg" in calls and "uwbcal-evk1000.elf verify reset exit" in calls
    assert "flashed" in capsys.readouterr().out


def test_no_image_says_make_firmware(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                     capsys: pytest.CaptureFixture[str]) -> None:
    root = make_repo(tmp_path / "repo", suffixes=())
    monkeypatch.chdir(root)
    monkeypatch.setenv("PATH", str(tmp_path))
    fake_tools(tmp_path, ("openocd",))
    assert main(["flash", "--dry-run"]) == 1
    err = capsys.readouterr().err.strip()
    assert "make firmware" in err and len(err.splitlines()) == 1


def test_missing_explicit_image(repo: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["flash", "--dry-run", "--image", "nope.elf", "--tool", "openocd"]) == 1
    assert "nope.elf does not exist" in capsys.readouterr().err


def test_no_tool_names_packages(repo: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["flash"]) == 1
    err = capsys.readouterr().err.strip()
    assert "no flashing tool found" in err and "stlink-tools" in err and "openocd" in err
    assert len(err.splitlines()) == 1


def test_named_tool_missing(repo: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["flash", "--tool", "st-flash"]) == 1
    assert "st-flash is not installed (Debian package stlink-tools)" in capsys.readouterr().err


def test_tool_failure_reports_exit_code(repo: Path, capsys: pytest.CaptureFixture[str]) -> None:
    fake_tools(Path(os.environ["PATH"]), ("openocd",), exit_code=3)
    assert main(["flash"]) == 1
    assert "openocd failed with exit code 3" in capsys.readouterr().err


def test_tool_failure_json(repo: Path, capsys: pytest.CaptureFixture[str]) -> None:
    fake_tools(Path(os.environ["PATH"]), ("st-flash",), exit_code=2)
    assert main(["flash", "--json"]) == 1
    err = json.loads(capsys.readouterr().out)           # with --json the error is JSON on stdout
    assert err["code"] == 1 and "st-flash failed with exit code 2" in err["error"]
