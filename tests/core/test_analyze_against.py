"""``hsa_analyze RUN --against REFERENCE`` (hsa_bag.against): a real run against itself, an offline
log (as ``hsa_experiment`` writes it) against a real run, and one-line refusals of what cannot be
compared."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hsa_bag import analysis
from hsa_core.analysis import sim_to_real
from hsa_core.runs.reference import load_run
from hsa_core.sim.experiment import replay_config, run_experiment

REAL = "20231019_143126"  # EPU P-satI-D: the quickest run to simulate


def run_cli(args: list[str], capsys) -> tuple[int, str, str]:
    """Exit code, stdout and stderr of hsa_analyze."""
    try:
        code = analysis.main(args)
    except SystemExit as exc:
        code = exc.code
    out = capsys.readouterr()
    return code, out.out, out.err


def test_a_real_run_against_itself_is_zero_apart(tmp_path: Path, capsys) -> None:
    code, out, err = run_cli([REAL, "--against", REAL, "--out", str(tmp_path)], capsys)
    assert code == 0, err
    doc = json.loads((tmp_path / "against.json").read_text())
    assert doc["deviation"] == 0.0 and doc["run"] == doc["reference"] == {
        "name": REAL,
        "kind": "real run",
    }
    assert [row["deviation"] for row in doc["steps"]] == [0.0] * 10
    for row in doc["steps"]:
        assert row["rise_time"]["run"] == row["rise_time"]["reference"]
        assert row["overshoot"]["run"] == row["overshoot"]["reference"]
    assert "D = 0.00 mm" in out and (tmp_path / "against.txt").read_text() in out
    for stem in ("against_xy", "against_steps"):
        assert (tmp_path / "figures" / f"{stem}.png").stat().st_size > 10_000
        assert (tmp_path / "figures" / f"{stem}.pdf").is_file()


def test_an_offline_log_against_the_real_run(tmp_path: Path, capsys) -> None:
    real = load_run(REAL)
    log = run_experiment(replay_config(real)).log
    (tmp_path / "replay").mkdir()
    path = log.save_npz(tmp_path / "replay" / "log.npz")
    code, out, err = run_cli([str(path), "--against", REAL, "--out", str(tmp_path / "o")], capsys)
    assert code == 0, err
    doc = json.loads((tmp_path / "o" / "against.json").read_text())
    assert doc["run"] == {"name": "replay", "kind": "log"}
    expected = sim_to_real.compare(
        sim_to_real.StepRun(log.t, log.chiee[:, :2], log.chiee_des[:, :2], 110.0),
        sim_to_real.StepRun(real.t, real.p, real.p_des, 110.0),
    )
    assert doc["deviation"] == expected.deviation and 0.0 < doc["deviation"] < 0.005
    steps = np.array([row["deviation"] for row in doc["steps"]])
    # D is the RMS of the steps'
    assert np.sqrt(np.mean(steps**2)) == pytest.approx(doc["deviation"], rel=1e-12)
    starts = np.array([row["start"]["reference"] for row in doc["steps"]])
    np.testing.assert_allclose(starts, real.step_instants, atol=1e-9)
    assert "replay (log) against 20231019_143126 (real run)" in out


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (
            ["nope_run", "--against", REAL],
            "nope_run: no such file, and not a real run of the paper",
        ),
        ([REAL, "--against", "{tmp}/bad.npz"], "not a RunLog NPZ file"),
        ([REAL, REAL, "--against", REAL], "--against compares one RUN with the reference, got 2"),
    ],
)
def test_what_cannot_be_compared_is_one_line_with_exit_2(
    tmp_path: Path, capsys, args, message
) -> None:
    (tmp_path / "bad.npz").write_bytes(b"not a zip file")
    code, _, err = run_cli(
        [a.format(tmp=tmp_path) for a in args] + ["--out", str(tmp_path / "o")], capsys
    )
    assert code == 2 and err.count("\n") == 1 and message in err, err
    assert not (tmp_path / "o").exists()
