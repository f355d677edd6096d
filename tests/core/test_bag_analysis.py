"""hsa_bag without ROS: split bag writing, crash recovery, ordered reading, bag → RunLog → metrics,
bad-bag errors.

The analysis is checked on a bag whose metrics are known by construction: an exponential step
response p_ee = p^d + (p_start − p^d)·r^k with r = exp(−dt/τ) at tick k of each step, so e_k =
|Δ|·r^k and RMSE, response time, steady-state error, saturation and rate follow in closed form
(computed here, not with hsa_core.analysis.metrics).
"""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from hsa_bag import analysis, bagrun
from hsa_bag.bagio import Bag, BagError
from hsa_bag.recover import recover_bag
from hsa_bag.storage import SplitBagWriter, read_metadata
from hsa_core.runs.runlog import RunLog

MSG_DIR = Path(__file__).resolve().parents[2] / "hsa_msgs" / "msg"
INFO = "hsa_msgs/msg/ControllerInfo"
STRING = "std_msgs/msg/String"
TRACKING, WAITING, STOPPED = 2, 0, 4

# the synthetic run: 4 steps of N ticks at DT, time constant TAU (TAU·ln10/DT and 2/DT are not
# integers, so no tick sits exactly on the 10 % threshold or the steady-state window edge)
DT, TAU, N = 0.03, 0.5, 100
TARGETS = [(0.0, 0.110), (0.010, 0.120), (-0.010, 0.115), (0.005, 0.105)]
START = (0.002, 0.108)  # measured position at t = 0
SATURATED_EVERY = 10


def store_with_hsa_msgs():
    """A Jazzy typestore with the hsa_msgs definitions from the source tree (independent of
    hsa_bag's registry)."""
    store = get_typestore(Stores.ROS2_JAZZY)
    for path in MSG_DIR.glob("*.msg"):
        store.register(get_types_from_msg(path.read_text(), f"hsa_msgs/msg/{path.stem}"))
    return store


STORE = store_with_hsa_msgs()
T = STORE.types


def stamp(ns: int):
    """builtin_interfaces/Time of ns."""
    return T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)


def info_msg(
    t_ns: int,
    state: int,
    p: tuple[float, float],
    p_des: tuple[float, float],
    k: int,
    trajectory_length: int = len(TARGETS),
    controller: str = "psatid",
    z_ee: float = 0.0,
) -> bytes:
    """Serialized ControllerInfo of one tick with measured p, setpoint p_des and recognisable other
    fields."""
    pose, cfg, setpoint = (
        T["hsa_msgs/msg/PlanarPose"],
        T["hsa_msgs/msg/CsConfiguration"],
        T["hsa_msgs/msg/Setpoint"],
    )
    sp = setpoint(
        header=T["std_msgs/msg/Header"](stamp=stamp(0), frame_id="hsa_base"),
        chiee_des=pose(p_des[0], p_des[1], 0.0),
        q_des=cfg(1.0, 0.0, 0.0),
        phi_ss=np.array([1.0, 2.0]),
        optimality_error=0.0,
        trajectory_index=0,
        trajectory_length=trajectory_length,
    )
    msg = T[INFO](
        header=T["std_msgs/msg/Header"](stamp=stamp(t_ns), frame_id="hsa_base"),
        state_stamp=stamp(t_ns),
        controller=controller,
        state=state,
        setpoint=sp,
        chiee=pose(p[0], p[1], 0.01 * k),
        chiee_des=pose(p_des[0], p_des[1], -0.02),
        q=cfg(float(k), 0.1, 0.2),
        q_des=cfg(1.0, 0.0, 0.0),
        q_dot=cfg(0.0, 0.0, 0.0),
        varphi=np.array([k, 2.0, 3.0]),
        varphi_des=np.array([1.0, 2.0, 3.0]),
        e_int=np.array([0.5 * k, 0.0]),
        z_ee=np.array([z_ee, 0.0]),
        phi_ss=np.array([1.0, 2.0]),
        phi_des_unsat=np.array([k, -1.0]),
        phi_des_sat=np.array([k, 0.0]),
        motor_goal_angles=np.zeros(4),
        saturated=(k % SATURATED_EVERY == 0),
        state_age=0.0,
        compute_time=0.0,
    )
    return STORE.serialize_cdr(msg, INFO)


def step_response() -> list[tuple[int, int, tuple[float, float], tuple[float, float], int]]:
    """(stamp ns, state, p, p_des, tracking tick index) of the synthetic run, with non-tracking
    ticks around it."""
    t0 = 1_700_000_000 * 10**9
    dt = round(DT * 1e9)
    ticks = [(t0 + j * dt, WAITING, (9.0, 9.0), (0.0, 0.0), -1) for j in range(10)]
    start_ns = t0 + 10 * dt
    r = math.exp(-DT / TAU)
    for i, target in enumerate(TARGETS):
        p_start = START if i == 0 else TARGETS[i - 1]
        for k in range(N):
            p = tuple(target[c] + (p_start[c] - target[c]) * r**k for c in range(2))
            index = i * N + k
            ticks.append((start_ns + index * dt, TRACKING, p, target, index))
    end = start_ns + len(TARGETS) * N * dt
    ticks += [(end + j * dt, STOPPED, (9.0, 9.0), TARGETS[-1], -1) for j in range(5)]
    return ticks


def write_info_bag(
    path: Path, ticks, topic: str = analysis.TOPIC, trajectory_length: int = len(TARGETS)
) -> Path:
    """A rosbags-written bag of ControllerInfo ticks; receive times jittered 0–3 ms after the header
    stamps."""
    rng = np.random.default_rng(1)
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conn = writer.add_connection(topic, INFO, typestore=STORE)
        for t_ns, state, p, p_des, k in ticks:
            writer.write(
                conn,
                t_ns + int(rng.integers(0, 3_000_000)),
                info_msg(t_ns, state, p, p_des, k, trajectory_length),
            )
    return path


def expected(kept: list[int]) -> dict[str, float]:
    """Closed-form metrics when ``kept[i]`` ticks of step i are used (step i's end is N ticks after
    its start)."""
    r = math.exp(-DT / TAU)
    sizes = [
        math.dist(TARGETS[i], START if i == 0 else TARGETS[i - 1]) for i in range(len(TARGETS))
    ]
    squares = sum(d**2 * (1 - r ** (2 * m)) / (1 - r**2) for d, m in zip(sizes, kept))
    late = math.ceil(N - 2.0 / DT)  # first tick index in the last 2 s of a full step
    e_ss = [d * sum(r**k for k in range(late, N)) / (N - late) for d in sizes]
    return {
        "rmse": math.sqrt(squares / sum(kept)),
        "t_r": (math.floor(TAU * math.log(10) / DT) + 1) * DT,
        "e_ss_mean": float(np.mean(e_ss[1:])),
        "saturated": sum(1 for k in range(sum(kept)) if k % SATURATED_EVERY == 0) / sum(kept),
    }


@pytest.fixture(scope="module")
def info_bag(tmp_path_factory) -> Path:
    return write_info_bag(tmp_path_factory.mktemp("analysis") / "step_run", step_response())


# --- bag → RunLog → metrics
# ---------------------------------------------------------------------------------------


def test_runlog_from_bag_keeps_tracking_ticks_with_header_time(info_bag: Path) -> None:
    log = bagrun.runlog_from_bag(info_bag)
    n = len(TARGETS) * N
    assert len(log) == n  # 10 waiting and 5 stopped ticks dropped
    # header stamps, not the jittered receive times
    np.testing.assert_allclose(log.t, np.arange(n) * DT, atol=1e-9)
    k = np.arange(n)
    np.testing.assert_allclose(log.chiee[:, 2], 0.01 * k)
    np.testing.assert_allclose(log.chiee_des[:, 2], -0.02)
    np.testing.assert_allclose(log.q[:, 0], k)
    np.testing.assert_allclose(log.varphi[:, 0], k)
    np.testing.assert_allclose(log.phi_unsat, np.column_stack([k, -np.ones(n)]))
    np.testing.assert_allclose(log.phi_sat, np.column_stack([k, np.zeros(n)]))
    np.testing.assert_allclose(log.e_int[:, 0], 0.5 * k)
    np.testing.assert_array_equal(log.saturated, k % SATURATED_EVERY == 0)
    assert log.meta["controller"] == "psatid" and log.meta["trajectory_length"] == str(len(TARGETS))
    assert (
        log.meta["ee_integral"] == "false"
        and "material" not in log.meta
        and "setup" not in log.meta
    )
    assert log.phi_meas is None  # no /hsa/phi_present in this bag
    assert not analysis.is_contour(log)


def test_metrics_match_the_closed_form_step_response(info_bag: Path, tmp_path: Path) -> None:
    result = analysis.analyze(info_bag, tmp_path)  # run shorter than 110 s: nothing trimmed
    want = expected([N] * len(TARGETS))
    m = result.metrics
    assert m.n_ticks == len(TARGETS) * N
    assert m.rmse == pytest.approx(want["rmse"], rel=1e-9)
    assert m.response_time_mean == pytest.approx(want["t_r"], abs=1e-9) and m.n_not_reached == 0
    assert m.steady_state_error_mean == pytest.approx(want["e_ss_mean"], rel=1e-9)
    assert m.saturated_fraction == pytest.approx(want["saturated"])
    assert m.control_rate == pytest.approx(1.0 / DT)
    assert [s.t_start for s in m.steps] == pytest.approx([i * N * DT for i in range(len(TARGETS))])


def test_duration_trims_the_run(info_bag: Path, tmp_path: Path) -> None:
    cut = (2 * N + 50.5) * DT  # halfway through the third step, between two ticks
    result = analysis.analyze(info_bag, tmp_path, duration=cut)
    kept = [N, N, 51, 0]
    assert result.metrics.n_ticks == len(result.log) == sum(kept)
    assert result.metrics.rmse == pytest.approx(expected(kept[:3])["rmse"], rel=1e-9)
    assert result.log.t[-1] < cut


def test_cli_writes_tables_figures_and_exports(info_bag: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "report"
    assert analysis.main([str(info_bag), "--out", str(out), "--csv", "--npz"]) == 0
    printed = capsys.readouterr().out
    assert "RMSE [mm]" in printed and "step" in printed
    assert f"{expected([N] * 4)['rmse'] * 1e3:.2f}" in printed
    assert {p.name for p in out.iterdir()} == {
        "metrics.txt",
        "run.csv",
        "run.npz",
        "figures",  # README layout
    }
    figures = ("end_effector", "steps", "path", "actuation", "configuration", "collocated")
    assert {p.name for p in (out / "figures").iterdir()} == {
        f"{f}.{x}" for f in figures for x in ("pdf", "png")
    }
    assert "RMSE [mm]" in (out / "metrics.txt").read_text()
    saved = RunLog.load_npz(out / "run.npz")
    np.testing.assert_allclose(saved.chiee, bagrun.runlog_from_bag(info_bag).chiee)
    header = (out / "run.csv").read_text().splitlines()[0].split(",")
    assert (
        header[:4] == ["t [s]", "chiee_x [m]", "chiee_y [m]", "chiee_theta [rad]"]
        and "phi_sat_2 [rad]" in header
    )
    assert len((out / "run.csv").read_text().splitlines()) == 1 + len(TARGETS) * N


def test_contour_run_draws_the_path_and_is_not_trimmed(tmp_path: Path) -> None:
    dt = round(DT * 1e9)
    ticks = [
        (
            10**18 + k * dt,
            TRACKING,
            (0.01 * math.cos(0.1 * k), 0.11),
            (0.01 * math.cos(0.1 * k), 0.111),
            k,
        )
        for k in range(40)
    ]
    bag = write_info_bag(tmp_path / "contour", ticks, trajectory_length=40)
    result = analysis.analyze(bag, tmp_path / "out", duration=None)
    assert (tmp_path / "out" / "figures" / "path.png") in result.files
    assert not any(p.stem == "steps" for p in result.files)  # no step figure for a contour
    assert result.metrics.rmse == pytest.approx(0.001)


# --- measured φ, material and setup from the bag; overlays; NPZ runs
# ------------------------------------------------

PHI = "hsa_msgs/msg/PlanarActuation"
DIAG = "diagnostic_msgs/msg/DiagnosticArray"
PHI_PERIOD = 7_000_000  # ns: the driver's reads, not aligned with the 30 ms ticks


def phi_msg(t_ns: int, phi: tuple[float, float]) -> bytes:
    """Serialized PlanarActuation (measured twist) stamped t_ns."""
    msg = T[PHI](
        header=T["std_msgs/msg/Header"](stamp=stamp(t_ns), frame_id=""),
        source_stamp=stamp(0),
        phi=np.array(phi),
    )
    return STORE.serialize_cdr(msg, PHI)


def diag_msg(t_ns: int, statuses: list[tuple[str, dict[str, str]]]) -> bytes:
    """Serialized DiagnosticArray with the given (name, values) statuses."""
    status, kv = T["diagnostic_msgs/msg/DiagnosticStatus"], T["diagnostic_msgs/msg/KeyValue"]
    msg = T[DIAG](
        header=T["std_msgs/msg/Header"](stamp=stamp(t_ns), frame_id=""),
        status=[
            status(
                level=0,
                name=name,
                message="",
                hardware_id="",
                values=[kv(key=k, value=v) for k, v in values.items()],
            )
            for name, values in statuses
        ],
    )
    return STORE.serialize_cdr(msg, DIAG)


def write_full_bag(
    path: Path,
    controller: str = "psatid",
    nodes: tuple[str, ...] = ("sim_node",),
    material: str = "epu",
    custom: dict[str, str] | None = None,
    z_ee: float = 0.0,
) -> Path:
    """The step run with /hsa/phi_present (φ = (j·1e-3, 2) at stamp t0 + j·PHI_PERIOD) and
    /diagnostics."""
    ticks = step_response()
    t0, t_end = ticks[0][0], ticks[-1][0]
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        for key, value in (custom or {}).items():
            writer.set_custom_data(key, value)
        info = writer.add_connection(analysis.TOPIC, INFO, typestore=STORE)
        phi = writer.add_connection("/hsa/phi_present", PHI, typestore=STORE)
        diag = writer.add_connection("/diagnostics", DIAG, typestore=STORE)
        statuses = [("kinematics_node: estimator", {"received": "5", "material": material})]
        statuses += [(f"{node}: status", {"x": "1"}) for node in nodes]
        writer.write(diag, t0, diag_msg(t0, statuses))
        for t_ns, state, p, p_des, k in ticks:
            writer.write(
                info, t_ns, info_msg(t_ns, state, p, p_des, k, controller=controller, z_ee=z_ee)
            )
        for j in range((t_end - t0) // PHI_PERIOD):
            writer.write(
                phi, t0 + j * PHI_PERIOD + 1, phi_msg(t0 + j * PHI_PERIOD, (j * 1e-3, 2.0))
            )
    return path


def test_measured_phi_material_and_setup_come_from_the_bag(tmp_path: Path) -> None:
    log = bagrun.runlog_from_bag(write_full_bag(tmp_path / "sim_run"))
    first_tracking = step_response()[10][0]  # 10 waiting ticks come first
    t0 = step_response()[0][0]
    for k in (0, 1, 17, len(log) - 1):  # the newest measurement at or before the tick
        tick = first_tracking + round(log.t[k] * 1e9)
        j = max(i for i in range(10**6) if t0 + i * PHI_PERIOD <= tick)
        np.testing.assert_allclose(log.phi_meas[k], [j * 1e-3, 2.0], atol=1e-12)
    assert (
        log.meta["material"] == "epu"
        and log.meta["setup"] == "sim"
        and log.meta["ee_integral"] == "false"
    )
    # EPU's φ_max (epu.yaml, 270°)
    assert float(log.meta["phi_max"]) == pytest.approx(4.7123890, abs=1e-6)

    robot = bagrun.runlog_from_bag(
        write_full_bag(tmp_path / "robot_run", nodes=("dynamixel_driver",))
    )
    assert robot.meta["setup"] == "robot" and robot.meta["material"] == "epu"
    told = bagrun.runlog_from_bag(
        write_full_bag(tmp_path / "told", custom={"setup": "robot", "material": "fpu"})
    )
    assert told.meta["setup"] == "robot" and told.meta["material"] == "fpu"  # custom_data wins
    eei = bagrun.runlog_from_bag(write_full_bag(tmp_path / "eei", z_ee=0.01))
    assert eei.meta["ee_integral"] == "true"


def test_figures_of_a_bag_name_the_run_and_draw_measured_phi(tmp_path: Path) -> None:
    from hsa_core.analysis import plotting

    bag = write_full_bag(tmp_path / "pid_run", controller="pid")
    result = analysis.analyze(bag, tmp_path / "out")
    label = plotting.RunLabel.of(result.log, result.metrics.rmse)
    assert label.short == f"PID, EPU, sim: RMSE {expected([N] * 4)['rmse'] * 1e3:.2f} mm"
    fig = plotting.actuation_figure(result.log, label)
    for ax in fig.axes:
        assert [line.get_gid() for line in ax.get_lines()].count("measured") == 1
        # a PID run has no φ^ss
        assert "reference" not in [line.get_gid() for line in ax.get_lines()]
        assert sorted(
            line.get_ydata()[0] for line in ax.get_lines() if line.get_gid() == "limit"
        ) == [0.0, pytest.approx(4.7123890, abs=1e-6)]
    assert (tmp_path / "out" / "figures" / "actuation.pdf").is_file()


def test_several_runs_are_analysed_and_overlaid(tmp_path: Path, capsys) -> None:
    a = write_full_bag(tmp_path / "a" / "bag", controller="psatid")  # named after its parent: a
    b = write_full_bag(tmp_path / "pid_run", controller="pid")
    npz_run = tmp_path / "exp" / "epu_psatid"
    npz_run.mkdir(parents=True)
    bagrun.runlog_from_bag(a).save_npz(npz_run / "log.npz")  # an offline experiment's log
    out = tmp_path / "cmp"
    assert analysis.main([str(a), str(b), str(npz_run / "log.npz"), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert {p.name for p in out.iterdir()} == {
        "a",
        "pid_run",
        "epu_psatid",
        "figures",
        "metrics.txt",
    }
    for name in ("a", "pid_run", "epu_psatid"):
        assert (out / name / "metrics.txt").is_file() and (
            out / name / "figures" / "end_effector.pdf"
        ).is_file()
    overlays = {p.name for p in (out / "figures").iterdir()}
    assert overlays == {
        f"overlay_{f}.{x}"
        for f in ("end_effector", "steps", "path", "actuation")
        for x in ("pdf", "png")
    }
    table = (out / "metrics.txt").read_text()
    rmse = f"{expected([N] * 4)['rmse'] * 1e3:.2f}"
    assert all(name in table for name in ("a", "pid_run", "epu_psatid")) and table.count(rmse) == 3
    assert printed.count(rmse) >= 3


def test_two_runs_of_the_same_name_are_kept_apart(tmp_path: Path) -> None:
    a = write_full_bag(tmp_path / "x" / "run1")
    b = write_full_bag(tmp_path / "y" / "run1")
    assert analysis.main([str(a), str(b), "--out", str(tmp_path / "o")]) == 0
    assert {"run1", "run1_2"} <= {p.name for p in (tmp_path / "o").iterdir()}


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["{bag}", "{bag}", "--name", "x"], "--name names one run"),
        (["{bag}", "/nonexistent/bag"], "/nonexistent/bag does not exist"),
        ([], "the following arguments are required: RUN"),
    ],
)
def test_bad_arguments_are_one_line_with_exit_2(
    info_bag: Path, tmp_path: Path, capsys, args, message
) -> None:
    with pytest.raises(SystemExit) as exit_info:
        analysis.main([a.format(bag=info_bag) for a in args] + ["--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert exit_info.value.code == 2 and err.count("\n") == 1 and message in err, err
    assert not (tmp_path / "o").exists()


def test_npz_that_is_not_a_runlog_is_refused(tmp_path: Path, capsys) -> None:
    np.savez(tmp_path / "other.npz", x=np.zeros(3))
    code, err = run_cli([str(tmp_path / "other.npz"), "--out", str(tmp_path / "o")], capsys)
    assert code == 2 and "not a RunLog NPZ file" in err


def garbage(k: int) -> bytes:
    """The k-th of four malformed CDR payloads: truncated, garbage, encapsulation only, invalid
    UTF-8 in a string."""
    good = bytes(info_msg(0, TRACKING, (0.0, 0.0), (0.0, 0.0), 0))
    return [
        good[: len(good) // 2],
        b"\x00\x01\x00\x00" + b"\xff" * 40,
        b"\x00\x01\x00\x00",
        good[:16] + b"\xff\xfe" + good[18:],
    ][k % 4]


def test_undecodable_messages_are_skipped_and_reported_per_topic(tmp_path: Path, capsys) -> None:
    spoiled = {analysis.TOPIC: 7, "/hsa/phi_present": 5, "/diagnostics": 3}
    t0 = step_response()[0][0]
    # the recorder's writer, malformed payloads among the real ones
    bag = SplitBagWriter(tmp_path / "spoiled", STORE)
    bag.open()
    with Bag(write_full_bag(tmp_path / "clean")) as clean:
        handles = {
            name: bag.add_topic(name, info.msgtype, []) for name, info in clean.topics.items()
        }
        for topic, t, raw in clean.messages():
            bag.write(handles[topic], t, raw)
    for topic, count in spoiled.items():
        for k in range(count):
            bag.write(handles[topic], t0 + k * 1_000_000_000 + 123, garbage(k))
    bag.close()

    out = tmp_path / "report"
    assert analysis.main([str(tmp_path / "spoiled"), "--out", str(out)]) == 0
    captured = capsys.readouterr()
    assert f"{expected([N] * 4)['rmse'] * 1e3:.2f}" in captured.out  # the run is whole
    lines = captured.err.splitlines()
    for topic, count in spoiled.items():
        assert (
            sum(f"skipped {count} undecodable message(s) on {topic}" in line for line in lines) == 1
        ), lines
    log = bagrun.runlog_from_bag(tmp_path / "spoiled")
    reference = bagrun.runlog_from_bag(tmp_path / "clean")
    np.testing.assert_array_equal(log.chiee, reference.chiee)
    np.testing.assert_array_equal(log.phi_meas, reference.phi_meas)
    assert log.meta["setup"] == "sim" and log.meta["material"] == "epu"
    assert analysis.skipped_messages(log) == spoiled and analysis.skipped_messages(reference) == {}


# --- bad bags
# --------------------------------------------------------------------------------------------------


def run_cli(args: list[str], capsys) -> tuple[int, str]:
    """Exit code and stderr of hsa_analyze."""
    code = analysis.main(args)
    return code, capsys.readouterr().err


def test_truncated_file_is_named(info_bag: Path, tmp_path: Path, capsys) -> None:
    bag = shutil.copytree(info_bag, tmp_path / "bag")
    mcap = next(bag.glob("*.mcap"))
    mcap.write_bytes(mcap.read_bytes()[: mcap.stat().st_size // 2])
    code, err = run_cli([str(bag), "--out", str(tmp_path / "o")], capsys)
    assert (
        code == 2
        and mcap.name in err
        and "not a complete MCAP file" in err
        and "bag_recover" in err
    )


def test_missing_metadata_is_named(info_bag: Path, tmp_path: Path, capsys) -> None:
    bag = shutil.copytree(info_bag, tmp_path / "bag")
    (bag / "metadata.yaml").unlink()
    code, err = run_cli([str(bag), "--out", str(tmp_path / "o")], capsys)
    assert code == 2 and "metadata.yaml is missing" in err and "bag_recover" in err


def test_missing_listed_file_is_named(info_bag: Path, tmp_path: Path, capsys) -> None:
    bag = shutil.copytree(info_bag, tmp_path / "bag")
    mcap = next(bag.glob("*.mcap"))
    mcap.unlink()
    code, err = run_cli([str(bag), "--out", str(tmp_path / "o")], capsys)
    assert code == 2 and f"file {mcap.name} listed in metadata.yaml is missing" in err


def test_missing_topic_is_named(info_bag: Path, tmp_path: Path, capsys) -> None:
    code, err = run_cli(
        [str(info_bag), "--topic", "/robot/controller_info", "--out", str(tmp_path)], capsys
    )
    assert (
        code == 2
        and "topic /robot/controller_info is not in the bag" in err
        and analysis.TOPIC in err
    )


def test_wrong_and_undecodable_types_are_named(tmp_path: Path, capsys) -> None:
    with Writer(tmp_path / "wrong", version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conn = writer.add_connection(analysis.TOPIC, STRING, typestore=STORE)
        writer.write(conn, 1, STORE.serialize_cdr(T[STRING](data="x"), STRING))
    code, err = run_cli([str(tmp_path / "wrong"), "--out", str(tmp_path / "o")], capsys)
    assert code == 2 and f"has type {STRING}, expected {INFO}" in err

    # a definition without its nested types (as a broken tool might store it): Setpoint etc. are
    # unknown
    msgdef = (MSG_DIR / "ControllerInfo.msg").read_text()
    with Writer(tmp_path / "undecodable", version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conn = writer.add_connection(
            analysis.TOPIC, INFO, msgdef=msgdef, rihs01="RIHS01_" + "0" * 64
        )
        writer.write(conn, 1, info_msg(1, TRACKING, (0, 0), (0, 0), 0))
    code, err = run_cli([str(tmp_path / "undecodable"), "--out", str(tmp_path / "o")], capsys)
    assert code == 2 and f"type {INFO} of topic {analysis.TOPIC} cannot be decoded" in err
    assert "lacks the nested type std_msgs/msg/Header" in err


def test_bag_without_tracking_ticks_is_refused(tmp_path: Path, capsys) -> None:
    ticks = [(10**18 + k, WAITING, (0, 0), (0, 0), k) for k in range(5)]
    code, err = run_cli(
        [str(write_info_bag(tmp_path / "idle", ticks)), "--out", str(tmp_path / "o")], capsys
    )
    assert code == 2 and "0 tick(s) in STATE_TRACKING" in err


# --- writing: splits, metadata, crash safety, order
# ----------------------------------------------------------------

INFINITE = QosTime(9223372036, 854775807)
OFFER = Qos(
    QosHistory.UNKNOWN,
    0,
    QosReliability.BEST_EFFORT,
    QosDurability.TRANSIENT_LOCAL,
    INFINITE,
    INFINITE,
    QosLiveliness.AUTOMATIC,
    INFINITE,
    False,
)


def string(i: int) -> bytes:
    return STORE.serialize_cdr(T[STRING](data=f"message {i:05d}"), STRING)


def test_split_bag_layout_metadata_and_independent_readers(tmp_path: Path) -> None:
    path = tmp_path / "split"
    bag = SplitBagWriter(path, STORE, max_bytes=8_000, chunk_size=2_000)
    bag.open()
    text = bag.add_topic("/text", STRING, [OFFER])
    for i in range(600):
        bag.write(text, 10**9 + i * 10**6, string(i))
    bag.close()
    info = read_metadata(path)
    files = info["relative_file_paths"]
    assert len(files) >= 3 and files == [f"split_{k}.mcap" for k in range(len(files))]
    # no staging left over
    assert sorted(p.name for p in path.iterdir()) == sorted([*files, "metadata.yaml"])
    assert (
        info["version"] == 9
        and info["storage_identifier"] == "mcap"
        and info["message_count"] == 600
    )
    assert sum(f["message_count"] for f in info["files"]) == 600 and all(
        f["message_count"] for f in info["files"]
    )
    assert (
        info["duration"]["nanoseconds"] == 599 * 10**6
        and info["starting_time"]["nanoseconds_since_epoch"] == 10**9
    )
    topic = info["topics_with_message_count"][0]
    assert topic["message_count"] == 600
    assert topic["topic_metadata"]["offered_qos_profiles"][0]["durability"] == "transient_local"
    # + summary and footer written at close
    assert all((path / f).stat().st_size <= 8_000 + 3_000 for f in files)

    seen = []
    for (
        name
    ) in files:  # each split is a self-contained MCAP: the `mcap` reader with mcap_ros2 decoding
        with open(path / name, "rb") as handle:
            reader = make_reader(handle, decoder_factories=[DecoderFactory()])
            seen += [m.decoded_message.data for m in reader.iter_decoded_messages(topics=["/text"])]
    assert seen == [f"message {i:05d}" for i in range(600)]
    with Reader(path) as reader:  # rosbags reads the whole directory
        assert reader.message_count == 600 and reader.topics["/text"].msgcount == 600
    with Bag(path) as opened:
        assert opened.topics["/text"].qos == (OFFER,) and opened.topics["/text"].count == 600


def test_split_by_duration_and_refusing_an_existing_path(tmp_path: Path) -> None:
    bag = SplitBagWriter(tmp_path / "timed", STORE, max_duration=10**9)
    bag.open()
    text = bag.add_topic("/text", STRING, [])
    for i in range(35):
        bag.write(text, i * 10**8, string(i))  # 3.5 s at 10 Hz
    bag.close()
    assert [f["message_count"] for f in read_metadata(tmp_path / "timed")["files"]] == [
        10,
        10,
        10,
        5,
    ]
    with pytest.raises(FileExistsError):
        SplitBagWriter(tmp_path / "timed", STORE).open()


def test_killed_writer_loses_only_the_unflushed_chunk(tmp_path: Path) -> None:
    path = tmp_path / "killed"
    bag = SplitBagWriter(path, STORE, max_duration=10**9, chunk_size=1 << 20)
    bag.open()
    text = bag.add_topic("/text", STRING, [])
    for i in range(150):  # split 0 closed at 1 s; split 1 open
        bag.write(text, i * 10**7, string(i))
    bag.flush()
    for i in range(150, 170):  # never flushed
        bag.write(text, i * 10**7, string(i))
    # what the disk holds if the process dies now
    crashed = shutil.copytree(path, tmp_path / "on_disk")
    bag.close()

    assert read_metadata(crashed)["relative_file_paths"] == ["killed_0.mcap"]
    with Reader(crashed) as reader:  # the closed split is a complete bag already
        assert reader.message_count == 100
    with pytest.raises(BagError, match="killed_1.mcap|bag_recover"):
        Bag(crashed / "killed_1.mcap")
    results = recover_bag(crashed)
    assert [(r.file.name, r.messages) for r in results] == [("killed_1.mcap", 50)]
    assert sorted(p.name for p in crashed.iterdir()) == [
        "killed_0.mcap",
        "killed_1.mcap",
        "metadata.yaml",
    ]
    with Bag(crashed) as reader:
        assert [data for _, _, data in reader.messages()] == [string(i) for i in range(150)]
    assert recover_bag(crashed) == []  # idempotent


def test_messages_come_in_timestamp_order_across_files(tmp_path: Path) -> None:
    path = tmp_path / "interleaved"
    bag = SplitBagWriter(path, STORE, max_bytes=6_000)
    bag.open()
    text = bag.add_topic("/text", STRING, [])
    order = [*range(0, 200, 2), *range(1, 200, 2)]  # evens, then odds: file order != time order
    for i in order:
        bag.write(text, i * 10**6, string(i))
    bag.close()
    assert len(read_metadata(path)["relative_file_paths"]) > 1
    with Reader(path) as reader:  # rosbags reads file after file
        assert [t for _, t, _ in reader.messages()] != sorted(t for _, t, _ in reader.messages())
    with Bag(path) as opened:
        got = list(opened.messages())
        assert [t for _, t, _ in got] == [i * 10**6 for i in range(200)]
        assert [d for _, _, d in got] == [string(i) for i in range(200)]
        assert [t for _, t, _ in opened.messages(start=150 * 10**6)][0] == 150 * 10**6


def test_written_bags_name_jazzy_as_their_distribution(tmp_path: Path) -> None:
    path = tmp_path / "distro"
    bag = SplitBagWriter(path, STORE, max_duration=10**9)
    bag.open()
    text = bag.add_topic("/text", STRING, [])
    for i in range(25):  # 2.5 s at 10 Hz: three splits
        bag.write(text, i * 10**8, string(i))
    bag.close()
    info = read_metadata(path)
    assert info["ros_distro"] == "jazzy" and len(info["files"]) == 3
    with Reader(path) as reader:
        assert reader.ros_distro == "jazzy"
    for name in info["relative_file_paths"]:  # the copy of the metadata embedded in every MCAP file
        with open(path / name, "rb") as handle:
            embedded = [
                m.metadata["serialized_metadata"] for m in make_reader(handle).iter_metadata()
            ]
        assert (
            len(embedded) == 1
            and "ros_distro: jazzy" in embedded[0]
            and "rosbags" not in embedded[0]
        )
