"""The command-line tools of hsa_identification on NPZ records simulated from known parameters (no
ROS needed).

hsa_identify must write a parameter file that loads with the constants the records were simulated
with; hsa_verify must find zero error once it has calibrated the record's rest strains from its
first half second (and a clear error without that calibration); hsa_workspace writes its figure and
data.
"""

from __future__ import annotations

import json
from pathlib import Path

import jax
import numpy as np
import pytest
import yaml
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from hsa_core.model import kinematics, simulation
from hsa_core.model.params import load_params
from hsa_core.sysid import excitation
from hsa_core.sysid import identification as ident
from hsa_core.task import planning
from hsa_identification import cli
from hsa_identification.records import load_record, payload_series, read_bag, save_npz
from tests.core.test_identification import RECORDS, SCALE, make_records


def test_identify_cli_writes_a_loadable_file_with_the_true_constants(tmp_path):
    base = load_params("fpu")
    per_rod = {key: value * SCALE[key] for key, value in ident.per_rod_constants(base).items()}
    truth = base.replace(
        **{k: np.full(2, v if k == "C_eps" else 2.0 * v) for k, v in per_rod.items()}
    )
    entries = []
    for rec, (_, role, _, _, _) in zip(make_records(truth, 0.0), RECORDS):
        # payload as a schedule in the campaign file for the first record, as an NPZ array for the
        # others
        first = not entries
        save_npz(
            tmp_path / f"{rec.name}.npz", rec.t, rec.chiee, rec.phi, None if first else rec.payload
        )
        entry = {"path": f"{rec.name}.npz", "role": role}
        if first:
            change = np.flatnonzero(np.diff(rec.payload)) + 1
            entry["payload"] = [[0.0, float(rec.payload[0])]] + [
                [float(rec.t[i]), float(rec.payload[i])] for i in change
            ]
        entries.append(entry)
    campaign = tmp_path / "campaign.yaml"
    campaign.write_text(yaml.safe_dump({"base_params": "fpu", "records": entries}))
    assert cli.identify_main([str(campaign), "--out", str(tmp_path / "out")]) == 0
    loaded = load_params(tmp_path / "out" / "identified.yaml")
    for key, value in per_rod.items():
        expected = value if key == "C_eps" else 2.0 * value
        np.testing.assert_allclose(np.asarray(getattr(loaded, key)), expected, rtol=1e-6)
    assert (tmp_path / "out" / "fit.png").is_file() and "step F" in (
        tmp_path / "out" / "report.txt"
    ).read_text()
    assert cli.identify_main([str(tmp_path / "missing.yaml")]) == 2


def test_payload_schedule_and_npz_records(tmp_path):
    t = np.arange(10.0)
    np.testing.assert_array_equal(
        payload_series(t, [[0, 0.0], [4, 0.2], [7, 0.0]]), [0, 0, 0, 0, 0.2, 0.2, 0.2, 0, 0, 0]
    )
    with pytest.raises(ValueError):
        payload_series(t, [[5, 0.1], [2, 0.0]])
    path = save_npz(tmp_path / "r.npz", t + 3.0, np.zeros((10, 3)), np.zeros((10, 2)))
    rec = load_record(path, "bending", 0.1)
    assert rec.t[0] == 0.0 and np.all(rec.payload == 0.1) and rec.name == "r"


def test_verify_cli_calibrates_the_rest_and_then_finds_zero_error(tmp_path):
    model = load_params("fpu")  # sigma_a_eq = 1
    plant = model.replace(sigma_a_eq=np.array([1.02, 0.99]))
    dt = 0.005
    exc = excitation.gbn(float(model.phi_max[0]), 1.5, seed=2, mode="combined")
    grid = np.arange(int(2.0 / dt)) * dt
    phi = np.where(grid[:, None] < 0.5, 0.0, excitation.zero_order_hold(exc.t + 0.5, exc.phi, grid))
    q0, _ = planning.static_equilibrium(plant, np.zeros(2), np.zeros(3))
    xs = np.asarray(
        simulation.simulate(plant, np.concatenate([q0, np.zeros(3)]), phi[:-1], dt / 20, 20)
    )
    chiee = np.asarray(jax.vmap(lambda q: kinematics.end_effector_pose(plant, q))(xs[:, :3]))
    save_npz(tmp_path / "gbn.npz", grid, chiee, phi)
    out = tmp_path / "v"
    assert cli.verify_main([str(tmp_path / "gbn.npz"), "--out", str(out)]) == 0
    metrics = json.loads((out / "metrics.json").read_text())["gbn"]
    assert metrics["rmse"]["x"] < 1e-7 and metrics["rmse"]["y"] < 1e-7
    assert "calibrated" in (out / "verification.txt").read_text() and (out / "gbn.png").is_file()
    assert cli.verify_main([str(tmp_path / "gbn.npz"), "--out", str(out), "--calibrate", "0"]) == 0
    uncalibrated = json.loads((out / "metrics.json").read_text())["gbn"]
    assert uncalibrated["rmse"]["y"] > 1e-4  # 0.5 % rest-strain error: ~0.2 mm axial offset
    assert cli.verify_main([str(tmp_path / "nothing.npz")]) == 2


def test_workspace_cli_writes_figure_and_data(tmp_path):
    assert cli.workspace_main(["--params", "fpu", "--n", "9", "--out", str(tmp_path)]) == 0
    with np.load(tmp_path / "workspace_fpu.npz") as data:
        assert data["chiee"].shape == (9, 9, 3) and np.all(data["residual"] < 1e-9)
    assert (tmp_path / "workspace_fpu.png").stat().st_size > 20_000
    assert cli.workspace_main(["--n", "2"]) == 2


def test_bag_records_hold_the_present_twist_onto_the_pose_stamps(tmp_path):
    """A bag with 200 Hz poses and 100 Hz present twists (other namespace, out-of-order and repeated
    pose stamps)."""
    store = get_typestore(Stores.ROS2_JAZZY)
    for msg in (Path(__file__).resolve().parents[2] / "hsa_msgs" / "msg").glob("*.msg"):
        store.register(get_types_from_msg(msg.read_text(), f"hsa_msgs/msg/{msg.stem}"))
    T = store.types
    t0 = 1_800_000_000 * 10**9

    def header(ns: int):
        return T["std_msgs/msg/Header"](
            stamp=T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9),
            frame_id="hsa_base",
        )

    pose_ns = [t0 + k * 5_000_000 for k in range(40)]
    phi_ns = [t0 + 2_000_000 + k * 10_000_000 for k in range(20)]
    with Writer(tmp_path / "bag", version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        pose_conn = writer.add_connection(
            "/robot/ee_pose", "hsa_msgs/msg/PlanarPoseStamped", typestore=store
        )
        phi_conn = writer.add_connection(
            "/robot/phi_present", "hsa_msgs/msg/PlanarActuation", typestore=store
        )
        order = list(range(40))
        order[10], order[11] = order[11], order[10]  # one swapped pair, one repeated pose
        for k in order + [5]:
            msg = T["hsa_msgs/msg/PlanarPoseStamped"](
                header=header(pose_ns[k]), pose=T["hsa_msgs/msg/PlanarPose"](0.001 * k, 0.11, 0.0)
            )
            writer.write(
                pose_conn,
                pose_ns[k] + 1000,
                store.serialize_cdr(msg, "hsa_msgs/msg/PlanarPoseStamped"),
            )
        for k, ns in enumerate(phi_ns):
            msg = T["hsa_msgs/msg/PlanarActuation"](
                header=header(ns), source_stamp=header(0).stamp, phi=np.array([0.1 * k, 0.0])
            )
            writer.write(
                phi_conn, ns + 1000, store.serialize_cdr(msg, "hsa_msgs/msg/PlanarActuation")
            )
    t, chiee, phi = read_bag(tmp_path / "bag")
    np.testing.assert_allclose(t, np.arange(40) * 0.005, atol=1e-9)
    np.testing.assert_allclose(chiee[:, 0], 0.001 * np.arange(40), atol=1e-15)
    # the newest twist read at or before each pose (the first one before the first read)
    expected = np.maximum(np.floor((np.arange(40) * 5 - 2) / 10), 0) * 0.1
    np.testing.assert_allclose(phi[:, 0], expected, atol=1e-12)
    assert load_record(tmp_path / "bag", "elongation").name == "bag"
