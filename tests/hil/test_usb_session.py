"""Calibration sessions over the EVK1000's USB link: two stations whose host link is the USB
driver on the OTG FS model (uwbcal.evk1000.usbstation), attached to the simulated medium, driven
by `uwbcal calibrate` through their ptys exactly as through /dev/ttyACM0.

What this cannot see: the ARM image (the driver and core run as host code, see
usb/hosted/hosted_board.c), a real host controller, real USB timing.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from uwbcal import cli
from uwbcal.evk1000.usbhosted import default_lib
from uwbcal.evk1000.usbstation import write_launcher
from uwbcal.sessions.store import Session
from uwbcal.simstations import SimWorld, repo_root

SCENARIO = repo_root() / "scenarios" / "two_stations.toml"
STEPS, PER_STEP = 5, 40


@pytest.fixture
def usb_world(sim_stations: Callable[..., SimWorld], tmp_path: Path) -> Callable[..., SimWorld]:
    """Two USB stations on the medium (conftest's sim_stations: each must exit cleanly)."""
    if not default_lib().exists():
        pytest.skip(f"{default_lib()} not built: run `make usbhosted`")
    launcher = write_launcher(tmp_path / "usbstation")

    def start(*extra: str) -> SimWorld:
        return sim_stations(scenario=SCENARIO, binary=launcher, extra_args=extra, start_timeout_s=60)

    return start


def calibrate(ports: list[str], out: Path, capsys: pytest.CaptureFixture[str]) -> dict[str, Any]:
    rc = cli.main(["calibrate", "--tx", ports[0], "--rx", ports[1], "--steps", str(STEPS), "--step-db", "3",
                   "--per-step", str(PER_STEP), "--spacing", "2ms", "--out", str(out), "--no-progress",
                   "--json", "--no-analysis"])
    text = capsys.readouterr().out
    assert rc == 0, text
    return dict(json.loads(text.strip().splitlines()[-1])["run"])


def assert_complete(run: dict[str, Any], db: Path) -> None:
    assert run["complete"] and run["records"] == STEPS * PER_STEP
    assert run["losses"]["lost_frames"] == 0 and run["losses"]["n_missing"] == 0
    assert run["losses"]["duplicates"] == 0
    with Session.open(db, readonly=True) as s:
        tr = s.read("triplets")
    assert sorted(tr["seq"].tolist()) == list(range(STEPS * PER_STEP))  # no duplicate, no gap
    assert np.bincount(tr["step"]).tolist() == [PER_STEP] * STEPS


def station_log(world: SimWorld, sid: int) -> str:
    world.stop()
    return next(s for s in world.stations if s.id == sid).log_path.read_text()


def test_calibration_over_usb_loses_no_record(usb_world: Any, tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    world = usb_world()
    from uwbcal.device import Device

    with Device.open(world.ports[1]) as dev:
        info = dev.info()
    assert info.board == "evk1000/hosted" and info.dev_id == 0xDECA0130  # the radio through the medium
    assert_complete(calibrate(world.ports, tmp_path / "cal.db", capsys), tmp_path / "cal.db")
    log = station_log(world, 2)
    assert re.search(r"tx dropped 0, tx failures 0", log), log


def test_port_reset_and_stalled_host_mid_session_nothing_lost(usb_world: Any, tmp_path: Path,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    # The receiver streams ~150 bytes per triplet: after ~8 KB (about a quarter of the session)
    # its port is reset and enumerated again; after ~16 KB its host stops reading bulk IN for
    # 60 ms of device time (the IN FIFO fills, then the station's TX ring).
    world = usb_world("--reset-after-bytes", "8000", "--stall-after-bytes", "16000", "--stall-us", "60000")
    assert_complete(calibrate(world.ports, tmp_path / "cal.db", capsys), tmp_path / "cal.db")
    log = station_log(world, 2)
    assert "port reset at" in log and "host stops reading at" in log, log  # both happened mid-session
    assert re.search(r"tx dropped 0, tx failures 0", log), log
    resets = int(re.findall(r"bus resets (\d+)", log)[-1])
    assert resets >= 4  # two per enumeration (Linux's "new scheme"), at start and after the reset
