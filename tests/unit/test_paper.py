"""`uwbcal paper`: the experiments run (quick sizes), the table and figures are written, and the
headline rows carry the paper's numbers beside the simulated ones."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from uwbcal import cli, paper


@pytest.fixture(scope="module")
def quick(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:  # type: ignore[type-arg]
    out = tmp_path_factory.mktemp("paper")
    return out, paper.run_paper(out, quick=True, seed=1)


def test_headline_rows(quick: tuple[Path, dict]) -> None:  # type: ignore[type-arg]
    _, r = quick
    rows = {row["name"]: row for row in r["headline"]}
    for row in r["headline"]:
        assert set(row) == {"name", "value", "unit", "paper", "note"}
    assert rows["drift: mean residual C'12 after eq. 1"]["paper"] == pytest.approx(-1.915e-5)
    assert rows["TWR paper: error std, 11 distances"]["paper"] == pytest.approx(0.015)
    names = " ".join(rows)
    for what in ("carrier integrator", "cable 3 dB", "antenna 0.5 dB", "measured vs real", "150 us",
                 "restarts", "two stations", "TWR ds", "TWR ss_carint", "aps011", "paper_no_power",
                 "paper_no_drift"):
        assert what in names, what
    # physics shows through: drift error before correction is metres, after it sub-millimetre
    assert abs(rows["drift: C12 mean before correction"]["value"]) > 1.0
    assert abs(rows["drift: mean residual C'12 after eq. 1"]["value"]) < 1e-3
    # the integrator jumps when only power changes, eq. 1 does not (by far)
    jump = rows["carrier integrator: error jump (minus truth)"]["value"]
    assert abs(jump) > 0.1  # ppm: 0.02 ppm/dB over a 10 dB drop
    assert abs(rows["eq. 1 drift estimate: error jump (minus truth) at the same moment"]["value"]) < 0.05
    # 150 us spacing shifts the curve, 2 ms does not
    assert abs(rows["spacing: C'12 at equal gains (step 0), 150 us"]["value"]) > 0.0005


def test_figures_and_table(quick: tuple[Path, dict]) -> None:  # type: ignore[type-arg]
    out, r = quick
    assert len(r["figures"]) >= 8
    for f in r["figures"]:
        p = Path(f)
        assert p.parent == out and p.stat().st_size > 5000
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    md = paper.table_markdown(r)
    assert md.count("\n") == len(r["headline"]) + 1
    assert "| 0.015 |" in md


def test_paper_cli_json(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["paper", "--out", str(tmp_path), "--quick", "--json", "--no-plots"]) == 0
    obj = json.loads(capsys.readouterr().out)
    assert isinstance(obj["headline"], list) and obj["headline"]
    assert {"name", "value", "unit", "paper"} <= set(obj["headline"][0])
    assert (tmp_path / "table.md").exists() and (tmp_path / "headline.json").exists()
    assert set(obj["bars"]) >= {"drift_abs_mean_le_1e-4_m", "twr_std_le_0.015_m"}
