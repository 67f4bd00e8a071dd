"""`--resume` port resolution of the session commands (commands/_session.resolve_ports)."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest
from uwbcal.commands._session import resolve_ports
from uwbcal.errors import SessionError
from uwbcal.sessions.runner import RunError
from uwbcal.sessions.store import Session


def _session(path: Path, settings: dict[str, object]) -> Path:
    with Session.create(path, {"kind": "power", "settings": settings}):
        pass
    return path


def test_new_session_needs_every_port() -> None:
    args = argparse.Namespace(resume=None, tx="/dev/pts/1", rx=None)
    with pytest.raises(RunError, match="--tx PORT and --rx PORT"):
        resolve_ports(args, "calibrate", ["tx", "rx"])


def test_resume_takes_stored_ports_and_keeps_given_ones(tmp_path: Path) -> None:
    db = _session(tmp_path / "s.db", {"command": "calibrate", "tx_port": "/dev/a", "rx_port": "/dev/b"})
    args = argparse.Namespace(resume=str(db), tx=None, rx="/dev/c")
    resolve_ports(args, "calibrate", ["tx", "rx"])
    assert (args.tx, args.rx) == ("/dev/a", "/dev/c")


def test_resume_of_another_command_is_refused(tmp_path: Path) -> None:
    db = _session(tmp_path / "s.db", {"command": "drift", "tx_port": "/dev/a", "rx_port": "/dev/b"})
    with pytest.raises(SessionError, match="not a calibrate session"):
        resolve_ports(argparse.Namespace(resume=str(db), tx=None, rx=None), "calibrate", ["tx", "rx"])


def test_resume_without_stored_port_names_the_missing_option(tmp_path: Path) -> None:
    db = _session(tmp_path / "s.db", {"command": "calibrate", "rx_port": "/dev/b"})
    with pytest.raises(SessionError, match="no tx port; give --tx PORT"):
        resolve_ports(argparse.Namespace(resume=str(db), tx=None, rx=None), "calibrate", ["tx", "rx"])
