"""Workspace map and the planner's reachability test (the paper's Fig. 1b; planning_and_control.md
§2).

Independent checks: the spec's steady state S1 (model.md §10), the packaged rest pose, polygon
geometry on shapes with known answers, and the map's own equilibria against the planner's region.
"""

from __future__ import annotations

import numpy as np
import pytest

from hsa_core.analysis import workspace
from hsa_core.model import dynamics, kinematics
from hsa_core.model.params import load_params
from hsa_core.task import planning
from hsa_core.task.planning import REACH_MARGIN, Planner


@pytest.fixture(scope="module")
def fpu():
    return load_params("fpu")


@pytest.fixture(scope="module")
def wmap(fpu):
    return workspace.workspace_map(fpu, n=9)


def test_boundary_walk_visits_every_edge_once():
    phis = workspace.boundary_phis([0.0, 0.0], [2.0, 3.0], n_per_edge=4)
    assert phis.shape == (16, 2)
    for corner in ([0, 0], [2, 0], [2, 3], [0, 3]):
        assert np.sum(np.all(phis == corner, axis=1)) == 1
    on_edge = (phis[:, 0] == 0) | (phis[:, 0] == 2) | (phis[:, 1] == 0) | (phis[:, 1] == 3)
    assert np.all(on_edge) and len(np.unique(phis, axis=0)) == 16


def test_region_geometry_on_a_square_with_margin():
    region = workspace.ReachabilityRegion([[0, 0], [1, 0], [1, 1], [0, 1]], margin=0.1)
    assert region.inside([0.5, 0.5]) and not region.inside([1.05, 0.5])
    assert region.distance([1.05, 0.5]) == pytest.approx(0.05)
    assert region.distance([2.0, 2.0]) == pytest.approx(np.sqrt(2.0))
    assert (
        region.contains([1.05, 0.5])
        and not region.contains([1.2, 0.5])
        and not region.contains([5.0, 5.0])
    )
    concave = workspace.ReachabilityRegion([[0, 0], [2, 0], [2, 2], [1, 0.5], [0, 2]], margin=0.0)
    assert not concave.inside([1.0, 1.5]) and concave.inside([1.0, 0.25])  # the notch is outside
    with pytest.raises(ValueError):
        workspace.ReachabilityRegion([[0, 0], [1, 1]], 0.1)


def test_map_equilibria_are_static_solutions_and_match_the_spec(fpu, wmap):
    assert wmap.chiee.shape == (9, 9, 3) and np.all(wmap.residual < 1e-10)
    np.testing.assert_allclose(wmap.mean_actuation, wmap.phi.mean(axis=-1))
    assert wmap.phi[-1, -1].tolist() == pytest.approx([float(fpu.phi_max[0])] * 2)
    for i, j in ((0, 0), (8, 0), (3, 5), (8, 8)):
        r = dynamics.static_residual(fpu, wmap.q[i, j], wmap.phi[i, j])
        assert np.linalg.norm(np.asarray(r)) < 1e-10
    # rest: the FPU robot hangs straight at y = 0.11014 m (docs/nodes/hsa_sim_node.md)
    np.testing.assert_allclose(wmap.chiee[0, 0], [0.0, 0.11014, 0.0], atol=5e-6)
    # phi1 > phi2 bends towards +x (model.md §3)
    assert wmap.chiee[-1, 0, 0] > 0.02 and wmap.chiee[0, -1, 0] < -0.02
    # model.md §10 S1, exact model: phi = [2, 3] -> chiee = [-0.014657464, 0.13357871, 0.19616744]
    q, _ = planning.static_equilibrium(fpu, np.array([2.0, 3.0]), np.zeros(3))
    np.testing.assert_allclose(
        kinematics.end_effector_pose(fpu, q),
        [-0.014657464, 0.13357871, 0.19616744],
        rtol=0,
        atol=5e-9,
    )


def test_planner_region_holds_every_equilibrium_and_rejects_far_targets(fpu, wmap):
    planner = Planner(fpu)
    dense = wmap
    region = planner._region
    pts = dense.chiee[..., :2]
    for p in pts[1:-1, 1:-1].reshape(-1, 2):  # interior of the phi box: strictly inside the polygon
        assert region.inside(p)
    for p in np.concatenate(
        [pts[0], pts[-1], pts[:, 0], pts[:, -1]]
    ):  # its edges: on the polygon (chord sag)
        assert region.inside(p) or region.distance(p) < 2e-5
    rest_y = dense.chiee[0, 0, 1]
    assert not planner.in_reach_region([0.0, rest_y - REACH_MARGIN - 1e-3])  # above the rest pose
    # within the margin: the solver decides
    assert planner.in_reach_region([0.0, rest_y - REACH_MARGIN + 1e-3])


def test_workspace_figure_and_data(fpu, wmap, tmp_path):
    data = wmap.save_npz(tmp_path / "ws.npz")
    with np.load(data) as loaded:
        np.testing.assert_array_equal(loaded["chiee"], wmap.chiee)
        assert str(loaded["material"]) == "fpu"
    assert workspace.plot_workspace(fpu, wmap, tmp_path / "ws.png").stat().st_size > 20_000
