"""Run figures (hsa_core.analysis.plotting) and RunLog exports: what a paper figure must show,
checked on the drawn artists.

The runs are synthetic with known answers: the measured position is the reference plus a constant
(3, −4) mm offset, so ‖e‖ = 5 mm at every tick and the RMSE is 5.00 mm; three setpoints 5 s apart at
40 Hz.
"""

from __future__ import annotations

import re
from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import pytest

from hsa_core.analysis import plotting
from hsa_core.runs.runlog import RunLog

DT = 0.025
TARGETS = [(0.0, 0.120), (0.005, 0.128), (-0.035, 0.122)]
OFFSET = np.array([0.003, -0.004])  # m: ‖e‖ = 5 mm
PHI_MAX = 3.49  # rad
UNIT = re.compile(r"\[[^\]]+\]$")  # an axis label ends with its unit in brackets


def make_log(
    controller: str = "psatid",
    material: str = "fpu",
    phi_meas: bool = True,
    step: float = 5.0,
    **meta: str,
) -> RunLog:
    """Three steps of ``step`` s; measured = reference + OFFSET; recognisable φ and φ^ss; optional
    measured φ."""
    n_step = round(step / DT)
    p_des = np.repeat(np.array(TARGETS), n_step, axis=0)
    n = len(p_des)
    k = np.arange(n, dtype=float)
    pose_des = np.column_stack([p_des, np.zeros(n)])
    pose = np.column_stack([p_des + OFFSET, np.zeros(n)])
    phi_cmd = np.column_stack([1.0 + 0.1 * np.sin(k / 40), 2.0 + 0.1 * np.cos(k / 40)])
    zeros3 = np.zeros((n, 3))
    return RunLog(
        t=k * DT,
        chiee=pose,
        chiee_des=pose_des,
        q=zeros3,
        q_des=zeros3,
        varphi=zeros3,
        varphi_des=zeros3,
        phi_ss=np.tile([1.0, 2.0], (n, 1)),
        phi_unsat=phi_cmd,
        phi_sat=phi_cmd,
        e_int=np.zeros((n, 2)),
        saturated=np.zeros(n, dtype=bool),
        phi_meas=phi_cmd - 0.05 if phi_meas else None,
        meta={"controller": controller, "material": material, **meta},
    )


def lines(ax: plt.Axes, gid: str) -> list:
    """The lines of ``ax`` whose gid starts with ``gid``."""
    return [line for line in ax.get_lines() if (line.get_gid() or "").startswith(gid)]


def all_axes_labels(fig: plt.Figure) -> list[str]:
    """Every non-empty x and y axis label of the figure."""
    return [text for ax in fig.axes for text in (ax.get_xlabel(), ax.get_ylabel()) if text]


@pytest.fixture(autouse=True)
def close_figures():
    yield
    plt.close("all")


def test_every_figure_is_written_as_pdf_and_png(tmp_path: Path) -> None:
    paths = plotting.all_figures(make_log(), tmp_path, phi_max=PHI_MAX)
    stems = ["end_effector", "steps", "path", "actuation", "configuration", "collocated"]
    assert sorted(p.name for p in paths) == sorted(
        f"{s}.{fmt}" for s in stems for fmt in ("pdf", "png")
    )
    for path in paths:
        magic = b"%PDF" if path.suffix == ".pdf" else b"\x89PNG\r\n\x1a\n"
        assert path.read_bytes().startswith(magic) and path.stat().st_size > 5_000


def test_pdf_fonts_are_subset_once_per_glyph_set_and_the_files_stay_the_same(
    tmp_path: Path, monkeypatch
) -> None:
    """The Type 42 subsets are reused across figures: a second PDF of the same glyphs subsets
    nothing again, and both are byte for byte what matplotlib writes with its own subsetting."""
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "0")  # no creation date in the PDF
    with matplotlib.rc_context(plotting.STYLE):
        fig, ax = plotting.subplots(figsize=(3.0, 2.0))
        ax.plot([0.0, 1.0], [0.0, 1.0])
        ax.set_title(r"subset once: $\varphi_1$ [rad], Ω")
        plotting._font_subset.cache_clear()
        first = plotting.save(fig, tmp_path / "first.pdf").read_bytes()
        subset = plotting._font_subset.cache_info()
        second = plotting.save(fig, tmp_path / "second.pdf").read_bytes()
        again = plotting._font_subset.cache_info()
        fig.savefig(tmp_path / "matplotlib.pdf", dpi=120)  # matplotlib's own subsetting
    assert subset.misses >= 2 and again.misses == subset.misses  # text and math fonts
    assert again.hits == subset.hits + subset.misses
    assert second == first == (tmp_path / "matplotlib.pdf").read_bytes()


def test_contour_runs_get_no_step_figure(tmp_path: Path) -> None:
    names = {p.stem for p in plotting.all_figures(make_log(), tmp_path, contour=True)}
    assert "steps" not in names and "path" in names


@pytest.mark.parametrize(
    ("controller", "meta", "law", "who"),
    [
        ("psatid", {}, "P-satI-D", "FPU, sim"),  # an offline run (no bag): a simulation
        ("psatid_gc", {"bag": "b", "setup": "robot"}, "P-satI-D + GC", "FPU, robot"),
        ("pid", {"bag": "b", "setup": "sim"}, "PID", "FPU, sim"),
        (
            "psatid",
            {"bag": "b", "setup": "sim", "ee_integral": "true"},
            "P-satI-D + EE integral",
            "FPU, sim",
        ),
        (
            "psatid + EE integral",
            {},
            "P-satI-D + EE integral",
            "FPU, sim",  # the offline experiment's spelling
        ),
    ],
)
def test_titles_name_law_material_setup_and_rmse(
    controller: str, meta: dict, law: str, who: str
) -> None:
    log = make_log(controller, **meta)
    label = plotting.RunLabel.of(log)
    for fig in (
        plotting.end_effector_figure(log, label),
        plotting.actuation_figure(log, label, PHI_MAX),
        plotting.steps_figure(log, label),
        plotting.path_figure(log, label),
    ):
        title = fig._suptitle.get_text() if fig._suptitle else fig.axes[0].get_title()
        assert f"{law}, {who}: RMSE 5.00 mm" in title, title
        assert "psatid" not in title and "pid" not in title


def test_every_axis_label_carries_a_unit_and_uses_math_text() -> None:
    log = make_log()
    label = plotting.RunLabel.of(log)
    figures = [
        plotting.end_effector_figure(log, label),
        plotting.steps_figure(log, label),
        plotting.path_figure(log, label),
        plotting.actuation_figure(log, label, PHI_MAX),
        plotting.configuration_figure(log, label),
        plotting.collocated_figure(log, label),
        plotting.overlay_end_effector_figure([log, log], [label, label]),
        plotting.overlay_steps_figure([log, log], [label, label]),
        plotting.overlay_path_figure([log, log], [label, label]),
        plotting.overlay_actuation_figure([log, log], [label, label], PHI_MAX),
    ]
    for fig in figures:
        labels = all_axes_labels(fig)
        assert labels and all(UNIT.search(text) for text in labels), labels
        symbols = [text.rsplit(" [", 1)[0] for text in labels]
        assert all(s.startswith("$") for s in symbols), labels  # math text, not ASCII x_ee
        assert not any(re.search(r"[_^]", re.sub(r"\$[^$]*\$", "", text)) for text in labels), (
            labels
        )


def test_reference_is_dashed_and_drawn_on_top_of_the_measured_line() -> None:
    log = make_log()
    fig = plotting.end_effector_figure(log, plotting.RunLabel.of(log))
    for ax in fig.axes[:2]:
        (ref,), (measured,) = lines(ax, "reference"), lines(ax, "run:0")
        assert ref.get_zorder() > measured.get_zorder() and ref.get_linestyle() == "--"
        assert ref.get_color() != measured.get_color()


def test_error_panel_is_logarithmic_in_millimetres_with_the_rmse() -> None:
    log = make_log()
    fig = plotting.end_effector_figure(log, plotting.RunLabel.of(log))
    err_ax = fig.axes[2]
    assert err_ax.get_yscale() == "log" and "[mm]" in err_ax.get_ylabel()
    (err,) = lines(err_ax, "run:0")
    np.testing.assert_allclose(err.get_ydata(), 5.0)  # mm
    assert any(
        np.allclose(line.get_ydata(), 5.0) and "RMSE 5.00 mm" in line.get_label()
        for line in err_ax.get_lines()
    )


def test_step_figure_zooms_into_each_step() -> None:
    log = make_log()
    fig = plotting.steps_figure(log, plotting.RunLabel.of(log))
    assert len(fig.axes) == len(TARGETS)
    for i, ax in enumerate(fig.axes):
        assert ax.get_xlim() == pytest.approx((-0.25, 2.0))
        x, y = (line.get_ydata() for line in lines(ax, "run:0"))
        np.testing.assert_allclose(
            x[np.asarray(lines(ax, "run:0")[0].get_xdata()) >= 0], OFFSET[0] * 1e3
        )
        np.testing.assert_allclose(
            y[np.asarray(lines(ax, "run:0")[1].get_xdata()) >= 0], OFFSET[1] * 1e3
        )
        assert f"step {i + 1} at {5.0 * i:.1f} s" == ax.get_title()


def test_step_panels_stop_before_the_next_setpoint_change() -> None:
    log = make_log(step=2.0)  # the 2 s window then reaches the next change exactly
    fig = plotting.steps_figure(log, plotting.RunLabel.of(log))
    targets = np.array(TARGETS) * 1e3
    for i, ax in enumerate(fig.axes):
        seen = {round(float(v), 6) for line in lines(ax, "reference") for v in line.get_ydata()}
        before = targets[i - 1] - targets[i] if i else np.zeros(2)
        assert seen <= {0.0, *np.round(before, 6)}, seen  # never the next step's offset
        assert max(float(np.max(line.get_xdata())) for line in ax.get_lines()) < 2.0


@pytest.mark.parametrize(
    ("controller", "with_ss"), [("psatid", True), ("psatid_gc", True), ("pid", False)]
)
def test_actuation_draws_limits_measured_phi_and_phi_ss_only_for_laws_that_have_it(
    controller: str, with_ss: bool
) -> None:
    log = make_log(controller)
    fig = plotting.actuation_figure(log, plotting.RunLabel.of(log), PHI_MAX)
    for k, ax in enumerate(fig.axes):
        limits = sorted(float(line.get_ydata()[0]) for line in lines(ax, "limit"))
        assert limits == [0.0, PHI_MAX]
        (measured,) = lines(ax, "measured")
        np.testing.assert_allclose(measured.get_ydata(), log.phi_meas[:, k])
        ss = lines(ax, "reference")
        assert len(ss) == (1 if with_ss else 0)
        if with_ss:
            np.testing.assert_allclose(ss[0].get_ydata(), log.phi_ss[:, k])
    legend = [t.get_text() for t in fig.legends[0].get_texts()]
    assert any("ss" in t for t in legend) == with_ss and any("measured" in t for t in legend)


def test_actuation_limits_come_from_the_log_and_measured_phi_is_optional() -> None:
    log = make_log(phi_meas=False, phi_max="4.7123890")
    fig = plotting.actuation_figure(log, plotting.RunLabel.of(log))
    for ax in fig.axes:
        assert sorted(float(line.get_ydata()[0]) for line in lines(ax, "limit")) == [
            0.0,
            pytest.approx(4.712389),
        ]
        assert not lines(ax, "measured")


@pytest.mark.parametrize("n_runs", [2, 3, 5])
def test_overlay_draws_every_run_once_per_panel_with_a_legend(tmp_path: Path, n_runs: int) -> None:
    laws = ["psatid", "pid", "psatid_gc", "psatid", "pid"][:n_runs]
    logs = [make_log(law, material=("fpu", "epu")[i % 2]) for i, law in enumerate(laws)]
    labels = [plotting.RunLabel.of(log) for log in logs]
    figures = [
        plotting.overlay_end_effector_figure(logs, labels),
        plotting.overlay_path_figure(logs, labels),
        plotting.overlay_actuation_figure(logs, labels, PHI_MAX),
    ]
    for fig in figures:
        for ax in fig.axes:
            runs = sorted(line.get_gid() for line in lines(ax, "run:"))
            assert runs == sorted(f"run:{i}" for i in range(n_runs)), runs
    steps = plotting.overlay_steps_figure(logs, labels)
    assert all(
        len(lines(ax, "run:")) == n_runs and len(lines(ax, "reference")) == 1 for ax in steps.axes
    )
    legend = [t.get_text() for t in figures[0].legends[0].get_texts()]
    assert len([t for t in legend if "RMSE 5.00 mm" in t]) == n_runs
    assert "PID, EPU, sim: RMSE 5.00 mm" in legend
    paths = plotting.overlay_figures(logs, tmp_path)
    assert sorted(p.name for p in paths) == sorted(
        f"overlay_{s}.{fmt}"
        for s in ("end_effector", "steps", "path", "actuation")
        for fmt in ("pdf", "png")
    )


def test_overlay_needs_two_runs(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="at least 2 runs"):
        plotting.overlay_figures([make_log()], tmp_path)


def test_csv_header_names_the_unit_of_every_column(tmp_path: Path) -> None:
    header = (make_log().save_csv(tmp_path / "run.csv")).read_text().splitlines()[0].split(",")
    assert header[:4] == ["t [s]", "chiee_x [m]", "chiee_y [m]", "chiee_theta [rad]"]
    assert {
        "q_kappa_be [rad/m]",
        "q_sigma_sh [-]",
        "varphi_1 [N m/rad]",
        "phi_ss_1 [rad]",
        "phi_sat_2 [rad]",
        "e_int_1 [s]",
        "saturated [-]",
        "phi_meas_2 [rad]",
    } <= set(header)
    assert all(UNIT.search(col) for col in header)
    pid = (
        make_log("pid", phi_meas=False)
        .save_csv(tmp_path / "pid.csv")
        .read_text()
        .splitlines()[0]
        .split(",")
    )
    assert "e_int_1 [m s]" in pid and not any(c.startswith("phi_meas") for c in pid)


def test_measured_phi_survives_npz_and_trimming(tmp_path: Path) -> None:
    log = make_log()
    back = RunLog.load_npz(log.save_npz(tmp_path / "run.npz"))
    np.testing.assert_array_equal(back.phi_meas, log.phi_meas)
    cut = log.trimmed(1.0)
    assert len(cut) == 40 and cut.phi_meas.shape == (40, 2)
    assert (
        RunLog.load_npz(make_log(phi_meas=False).save_npz(tmp_path / "none.npz")).phi_meas is None
    )


def test_overlay_draws_each_distinct_reference_in_its_runs_colour() -> None:
    same = [make_log("psatid"), make_log("pid")]
    other = make_log("psatid_gc", material="epu")
    other.chiee_des[:, :2] += [0.002, 0.001]  # another step list (another material's)
    other.chiee[:, :2] += [0.002, 0.001]
    logs = [*same, other]
    labels = [plotting.RunLabel.of(log) for log in logs]
    fig = plotting.overlay_end_effector_figure(same, labels[:2])
    # shared: drawn once, black
    assert [line.get_color() for line in lines(fig.axes[0], "reference")] == ["k"]
    fig = plotting.overlay_end_effector_figure(logs, labels)
    for k, ax in enumerate(fig.axes[:2]):
        refs = lines(ax, "reference")
        assert [r.get_color() for r in refs] == ["C0", "C2"]  # the first run's and the EPU run's
        np.testing.assert_allclose(refs[1].get_ydata(), other.chiee_des[:, k] * 1e3)
    legend = [t.get_text() for t in fig.legends[0].get_texts()]
    assert any("P-satI-D + GC, EPU" in t and t.startswith("reference") for t in legend)
    steps = plotting.overlay_steps_figure(logs, labels)
    assert all(len(lines(ax, "reference")) == 2 for ax in steps.axes)
    path = plotting.overlay_path_figure(logs, labels)
    assert len(lines(path.axes[0], "reference")) == 2


def test_overlay_actuation_draws_each_materials_limit() -> None:
    logs = [make_log("psatid", phi_max="3.49"), make_log("pid", material="epu", phi_max="4.712389")]
    labels = [plotting.RunLabel.of(log) for log in logs]
    fig = plotting.overlay_actuation_figure(logs, labels)
    for ax in fig.axes:
        limits = {
            (round(float(line.get_ydata()[0]), 6), line.get_label()) for line in lines(ax, "limit")
        }
        assert {
            (3.49, r"$\phi_\mathrm{max}$ of FPU"),
            (4.712389, r"$\phi_\mathrm{max}$ of EPU"),
        } <= limits
        assert 0.0 in {v for v, _ in limits}
    same = plotting.overlay_actuation_figure([logs[0], logs[0]], [labels[0]] * 2)
    assert sorted(float(line.get_ydata()[0]) for line in lines(same.axes[0], "limit")) == [
        0.0,
        3.49,
    ]
