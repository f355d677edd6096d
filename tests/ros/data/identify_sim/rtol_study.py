"""Where RTOL of tests/ros/test_identify_e2e.py comes from: the campaign's holds, identified under
the declared noise.

Each hold of campaign.yaml (same levels and payloads, in the same order) is the simulated plant's
static equilibrium (packaged FPU set with the declared mismatch of hsa_core.sim.disturbance),
observed for one 1 s window at 200 Hz with the declared mocap noise; the script prints the largest
relative error of every constant over N seeds (default 60). Run: .venv/bin/python
tests/ros/data/identify_sim/rtol_study.py [N]
"""

from __future__ import annotations

import sys

import numpy as np

from hsa_core.jaxsetup import configure_jax

configure_jax()
from hsa_core.analysis.workspace import equilibrium_poses  # noqa: E402
from hsa_core.model.params import load_params  # noqa: E402
from hsa_core.sim.disturbance import DisturbanceModel  # noqa: E402
from hsa_core.sysid import identification as ident  # noqa: E402

RATE, WINDOW = 200.0, 1.0
# name, role, phi per level as fractions of phi_max, payload [kg] of the first half of level 0
RECORDS = [
    ("elong", "elongation", [(f, f) for f in np.linspace(0.0, 1.0, 3)], 0.4),
    ("bend_rod1", "bending", [(f, 0.0) for f in np.linspace(0.0, 1.0, 4)], 0.2),
    ("bend_rod2", "bending", [(0.0, f) for f in np.linspace(0.0, 1.0, 4)], 0.2),
]


def records(plant, rng: np.random.Generator) -> list[ident.Record]:
    """Two holds per level, unloaded and loaded alternating as in campaign.yaml (0, m | m, 0 | 0, m
    | ...)."""
    n, std, out = int(WINDOW * RATE), np.asarray(DisturbanceModel().pose_noise_std), []
    for name, role, levels, mass in RECORDS:
        phis = np.array(levels) * np.asarray(plant.phi_max)
        poses = {m: equilibrium_poses(plant.replace(m_pl=m), phis)[1] for m in (0.0, mass)}
        order = [(0.0, mass) if k % 2 == 0 else (mass, 0.0) for k in range(len(phis))]
        holds = [(poses[m][k], phis[k], m) for k in range(len(phis)) for m in order[k]]
        chiee = np.concatenate([pose + rng.normal(size=(n, 3)) * std for pose, _, _ in holds])
        phi = np.concatenate([np.tile(p, (n, 1)) for _, p, _ in holds])
        payload = np.concatenate([np.full(n, m) for _, _, m in holds])
        out.append(ident.Record(name, np.arange(len(chiee)) / RATE, chiee, phi, payload, role))
    return out


def main(n_seeds: int) -> None:
    """Print the largest relative error per constant over the seeds."""
    base = load_params("fpu")
    plant = DisturbanceModel().plant_params(base)
    truth = ident.per_rod_constants(plant)
    errors = []
    for seed in range(n_seeds):
        samples = ident.settled_samples(
            base, records(plant, np.random.default_rng(seed)), settle=0.0, window=WINDOW - 0.01
        )
        result = ident.identify(base, samples)
        errors.append([abs(result.values[k] / truth[k] - 1.0) for k in truth])
    print(", ".join(f"{k} {e:.2%}" for k, e in zip(truth, np.max(errors, axis=0))))


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 60)
