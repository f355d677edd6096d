"""Shared fixtures for the hsa_core model tests: parameter sets, jitted model functions, spec
reference values.

Every expected number in REFERENCE is copied from the specification (model.md §10); none comes from
running this code. Jitted functions take the parameters as a pytree argument, so each is compiled
once per (material, kappa_rule) and reused by every test that needs it.
"""

import jax
import numpy as np
import pytest

from hsa_core.model import dynamics, kinematics, simulation
from hsa_core.model.params import HsaParams, load_params


class Model:
    """Jitted model functions shared by all tests (compiled lazily, cached by JAX per static
    configuration)."""

    fk = jax.jit(kinematics.end_effector_pose)
    jee = jax.jit(kinematics.end_effector_jacobian)
    ik = jax.jit(kinematics.inverse_kinematics)
    dm = jax.jit(dynamics.dynamical_matrices)
    fd = jax.jit(dynamics.forward_dynamics)
    varphi = jax.jit(dynamics.collocated_map)
    J_h = jax.jit(dynamics.collocated_jacobian)
    residual = jax.jit(dynamics.static_residual)
    rk4 = jax.jit(simulation.rk4_step)
    rollout = jax.jit(simulation.steady_state_rollout, static_argnames=("duration", "dt"))


@pytest.fixture(scope="session")
def model() -> type[Model]:
    """The shared jitted model functions."""
    return Model


@pytest.fixture(scope="session")
def fpu() -> HsaParams:
    """FPU exp2023 parameters, exact kappa rule."""
    return load_params("fpu")


@pytest.fixture(scope="session")
def epu() -> HsaParams:
    """EPU exp2023 parameters, exact kappa rule."""
    return load_params("epu")


def params_for(material: str, kappa_rule: str = "exact") -> HsaParams:
    """Packaged parameter set with the given kappa rule."""
    return load_params(material, kappa_rule=kappa_rule)


def assert_printed(actual, expected, rtol: float = 1e-7, atol: float = 0.0, name: str = "") -> None:
    """Compare with values printed to 8 significant digits: |a - e| <= rtol |e| + atol, entry by
    entry."""
    actual, expected = np.asarray(actual, dtype=float), np.asarray(expected, dtype=float)
    assert actual.shape == expected.shape, f"{name}: shape {actual.shape} != {expected.shape}"
    err = np.abs(actual - expected)
    bound = rtol * np.abs(expected) + atol
    assert np.all(err <= bound), (
        f"{name}: max excess {np.max(err - bound):.3e}\nactual={actual}\nexpected={expected}"
    )


# model.md §10: inputs (full precision) and outputs (8 significant digits). "exact": smooth model
# without shift; "reference": original implementation with the exp2023 rule; "compat": R1 with the
# exp2023 rule, no cancellation error.
REFERENCE = {
    "R1": dict(
        material="fpu",
        q=[0.0, 0.0, 0.0],
        q_dot=[3.854640416775222, -0.4480424548974664, 0.7901790561078423],
        phi=[2.5421285355261904, 2.856580426497421],
        exact=dict(
            chiee=[0.0, 0.11, 0.0],
            M=[
                [8.1645776e-07, -1.3904338e-05, 0],
                [-1.3904338e-05, 0.00030796339, 0],
                [0, 0, 0.00030796339],
            ],
            G=[0, 0, -0.054392633],
            K=[0, 0, 0],
            alpha=[0.017748652, 0, 11.457288],
            A=[[-0.055799125, 0.057087157], [0, 0], [2.3249635, 2.3786315]],
            varphi=[2.5805847, 2.6342527, 0],
            q_ddot=[90757.023, 4098.956, 37174.895],
        ),
        reference=dict(
            chiee=[-3.259629e-09, 0.11, 5.9e-08],
            M=[
                [8.1246375e-07, -1.3909216e-05, -2.341677e-09],
                [-1.3909216e-05, 0.00030796338, 0],
                [-2.341677e-09, 0, 0.00030796338],
            ],
            G=[1.0764147e-06, -1.5105604e-05, -0.05439263],
            K=[0.00015336911, 0.00017936782, 0],
            alpha=[0.017750462, 0, 11.45725],
            A=[[-0.05579879, 0.057087492], [0, 0], [2.3250862, 2.3785088]],
            varphi=[2.5805847, 2.6342527, 0],
            q_ddot=[92660.008, 4185.7401, 37175.475],
        ),
        compat=dict(
            chiee=[-3.2745e-09, 0.11, 5.9e-08],
            M=[
                [8.1645775e-07, -1.3904338e-05, -2.3540023e-09],
                [-1.3904338e-05, 0.00030796338, 0],
                [-2.3540023e-09, 0, 0.00030796338],
            ],
            G=[1.0761842e-06, -1.5105604e-05, -0.05439263],
            q_ddot=[90372.558, 4081.0642, 37175.461],
        ),
    ),
    "R2": dict(
        material="fpu",
        q=[-8.863191643408808, 0.006772502908168665, 0.2977723514896258],
        q_dot=[1.32928918620863, -0.24750740544257332, 0.4417241163496959],
        phi=[1.2826032455346215, 1.7406114277481715],
        reference=dict(
            chiee=[0.032934381, 0.12054956, -0.52292837],
            M=[
                [1.0655172e-06, -1.6040228e-05, 2.3237864e-06],
                [-1.6040228e-05, 0.00030133937, 0],
                [2.3237864e-06, 0, 0.00030133937],
            ],
            G=[-0.0010791672, 0.013115195, -0.0521563],
            K=[-0.13596588, -0.14313379, 6.7471936],
            alpha=[0.021050805, 0.00033015534, 5.705741],
            A=[[-0.047283698, 0.048565054], [0.00010920672, 0.00010920672], [1.8488921, 2.1448059]],
            varphi=[3.3890188, 2.6409385, 0.0067725029],
            q_ddot=[891350.99, 47879.673, -10273.923],
        ),
        exact=dict(
            chiee=[0.032934378, 0.12054956, -0.52292831],
            M=[
                [1.0655507e-06, -1.6041302e-05, 2.3213422e-06],
                [-1.6041302e-05, 0.00030135415, 0],
                [2.3213422e-06, 0, 0.00030135415],
            ],
            G=[-0.0010780465, 0.013101057, -0.052161271],
            K=[-0.13581251, -0.14295442, 6.7471936],
            alpha=[0.021051818, 0.00033015534, 5.7056848],
            A=[[-0.047283363, 0.048565389], [0.00010920672, 0.00010920672], [1.8490148, 2.1446832]],
            varphi=[3.3890188, 2.6409385, 0.0067725029],
            q_ddot=[890473.4, 47833.24, -10259.599],
        ),
    ),
    "R3": dict(
        material="fpu",
        q=[13.939427921157904, 0.022368534691995345, 0.32123766394792064],
        q_dot=[7.573653186331924, 0.35662581078988875, 0.29472336664422216],
        phi=[2.030232175819998, 2.4822629559864557],
        reference=dict(
            chiee=[-0.048165599, 0.11266213, 0.82242631],
            M=[
                [1.0633563e-06, -1.5579038e-05, -3.2940049e-06],
                [-1.5579038e-05, 0.00029180584, 0],
                [-3.2940049e-06, 0, 0.00029180584],
            ],
            G=[0.0015865081, -0.019965923, -0.048972531],
            K=[0.21434236, 0.3031284, 7.2788917],
            alpha=[0.02502131, 0.0016276253, 8.5926459],
            A=[[-0.04929335, 0.052079841], [0.00036069297, 0.00036069297], [2.244524, 1.979359]],
            varphi=[2.4952632, 4.0102794, 0.022368535],
            q_ddot=[-987973.17, -53711.946, -6563.4046],
        ),
        exact=dict(
            chiee=[-0.048165596, 0.11266213, 0.82242625],
            M=[
                [1.0634109e-06, -1.5580663e-05, -3.2917528e-06],
                [-1.5580663e-05, 0.00029182849, 0],
                [-3.2917528e-06, 0, 0.00029182849],
            ],
            G=[0.0015855435, -0.019953159, -0.048980045],
            K=[0.21418899, 0.30294903, 7.2788917],
            alpha=[0.025019797, 0.0016276253, 8.5927014],
            A=[[-0.049293685, 0.052079505], [0.00036069297, 0.00036069297], [2.2444013, 1.9794816]],
            varphi=[2.4952632, 4.0102794, 0.022368535],
            q_ddot=[-987202.46, -53671.561, -6546.3616],
        ),
    ),
    "R4": dict(
        material="epu",
        q=[-2.106456099945632, 0.004301296196584689, 0.2067291393316677],
        q_dot=[0.44384640639517414, 0.3820223374342937, -0.7144993230497261],
        phi=[2.561584376537942, 2.376802418592096],
        reference=dict(
            chiee=[0.0078946426, 0.12179759, -0.12428097],
            M=[
                [1.0377725e-06, -1.6540617e-05, 5.895972e-07],
                [-1.6540617e-05, 0.00033919916, 0],
                [5.895972e-07, 0, 0.00033919916],
            ],
            G=[-0.00027128005, 0.0035213002, -0.0621449],
            K=[-0.0033658152, -0.0035318876, 0.6086957],
            alpha=[0.00059484674, -0.0021122275, 1.1755336],
            A=[
                [-0.0081290716, 0.008600766],
                [-0.00042771608, -0.00042771608],
                [0.33987915, 0.35719741],
            ],
            varphi=[0.69024589, 0.63513436, 0.0043012962],
            q_ddot=[12374.551, 596.31446, 2001.3134],
        ),
        exact=dict(
            chiee=[0.0078946389, 0.12179759, -0.12428091],
            M=[
                [1.0377798e-06, -1.6540878e-05, 5.8701082e-07],
                [-1.6540878e-05, 0.00033920297, 0],
                [5.8701082e-07, 0, 0.00033920297],
            ],
            G=[-0.00027003703, 0.0035047018, -0.06214621],
            K=[-0.0033498711, -0.0035117194, 0.6086957],
            alpha=[0.00058473298, -0.0021122275, 1.1755484],
            A=[
                [-0.0081311196, 0.008598718],
                [-0.00042771608, -0.00042771608],
                [0.33995897, 0.3571176],
            ],
            varphi=[0.69024589, 0.63513436, 0.0043012962],
            q_ddot=[12277.854, 591.59146, 2001.5999],
        ),
    ),
}
