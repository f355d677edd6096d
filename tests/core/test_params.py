"""Parameter loading, virtual-rod doubling, derived quantities and validation (model.md §2, §5)."""

import dataclasses
import math
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import yaml

from hsa_core.model.params import CONFIG_DIR, HsaParams, ParameterError, load_params

# model.md §5.3, per physical rod: (FPU, EPU)
PER_ROD = {
    "C_eps": (0.00984819, 0.0079049),
    "S_b_hat": (5.71346377e-4, -2.53938133e-5),
    "S_sh_hat": (5.91462074e-1, 4.28135773e-2),
    "S_a_hat": (5.66472469, 0.73610293),
    "S_b_sh": (4.48419541e-3, 5.04204068e-4),
    "C_S_b": (-9.67560524e-6, 3.90666351e-7),
    "C_S_sh": (-4.75687961e-4, 2.93344701e-3),
    "C_S_a": (0.01508165, 0.00981059),
    "zeta_b": (3e-5, 3e-5),
    "zeta_sh": (2e-4, 2e-4),
    "zeta_a": (2e-2, 2e-2),
    "rho_r": (798.38, 827.94),
    "rho_ec": (710.4, 710.4),
}
# model.md §5.2/§5.3, virtual rod (x2) as printed in the spec
VIRTUAL = {
    "S_b_hat": (1.142692754e-3, -5.07876266e-5),
    "S_sh_hat": (1.182924148, 0.0856271546),
    "S_a_hat": (11.32944938, 1.47220586),
    "S_b_sh": (8.96839082e-3, 1.008408136e-3),
    "C_S_b": (-1.935121048e-5, 7.81332702e-7),
    "C_S_sh": (-9.51375922e-4, 5.86689402e-3),
    "C_S_a": (0.0301633, 0.01962118),
    "zeta_b": (6e-5, 6e-5),
    "zeta_sh": (4e-4, 4e-4),
    "zeta_a": (4e-2, 4e-2),
    "rho_r": (1596.76, 1655.88),
    "rho_ec": (1420.8, 1420.8),
}
NOT_DOUBLED = {"C_eps": (0.00984819, 0.0079049), "phi_max": (math.radians(200), math.radians(270))}


@pytest.mark.parametrize("index, material", [(0, "fpu"), (1, "epu")])
def test_packaged_yaml_holds_per_physical_rod_values(index: int, material: str) -> None:
    raw = yaml.safe_load((CONFIG_DIR / f"{material}.yaml").read_text())
    for key, values in PER_ROD.items():
        assert raw[key] == [values[index]] * 2, key


@pytest.mark.parametrize("index, material", [(0, "fpu"), (1, "epu")])
def test_virtual_rod_values_are_doubled_exactly_as_model_section2(
    index: int, material: str
) -> None:
    p = load_params(material)
    assert p.material == material and p.kappa_rule == "exact"
    for key, values in VIRTUAL.items():
        np.testing.assert_allclose(
            np.asarray(getattr(p, key)), [values[index]] * 2, rtol=2e-9, err_msg=key
        )
    for key, values in NOT_DOUBLED.items():
        np.testing.assert_allclose(
            np.asarray(getattr(p, key)), [values[index]] * 2, rtol=1e-9, err_msg=key
        )
    # geometry and platform density are not doubled (model.md §2)
    np.testing.assert_array_equal(p.r_out, [0.0127, 0.0127])
    np.testing.assert_array_equal(p.r_in, [[0.01027, 0.00794][index]] * 2)
    np.testing.assert_array_equal(p.roff, [-0.024, 0.024])
    np.testing.assert_array_equal(p.h, [1.0, 1.0])
    assert (
        float(p.rho_p) == 925.0
        and float(p.l) == 0.059
        and float(p.l_pc) == 0.025
        and float(p.l_dc) == 0.014
    )
    np.testing.assert_array_equal(p.platform_size, [0.08, 0.012, 0.08])
    np.testing.assert_array_equal(p.g, [0.0, 9.81])
    np.testing.assert_array_equal(p.xi_eq, [0.0, 0.0, 1.0])


@pytest.mark.parametrize(
    "material, area, second_moment, rod_mass",
    [("fpu", 1.75355e-4, 1.16945e-8, 16.520e-3), ("epu", 3.08650e-4, 1.73102e-8, 30.154e-3)],
)
def test_derived_quantities_match_worked_numbers(
    material: str, area: float, second_moment: float, rod_mass: float
) -> None:
    p = load_params(material)
    np.testing.assert_allclose(p.area, area, rtol=5e-6)
    np.testing.assert_allclose(p.second_moment, second_moment, rtol=5e-6)
    np.testing.assert_allclose(p.rho_r * p.area * p.l, rod_mass, rtol=5e-5)  # mass of a virtual rod
    np.testing.assert_allclose(p.m_plate, 71.04e-3, rtol=1e-12)
    np.testing.assert_allclose(p.m_dc, 3.20825e-3, rtol=5e-6)  # no pi (identified convention)
    np.testing.assert_allclose(p.m_p, 77.4565e-3, rtol=1e-6)
    np.testing.assert_allclose(p.y_c, 18.9231e-3, rtol=5e-6)
    np.testing.assert_allclose(p.I_p, 4.009857e-5, rtol=2e-7)
    assert float(p.l_pc + p.l + p.l_dc + p.platform_size[1]) == pytest.approx(0.110, abs=1e-15)


def test_params_is_an_immutable_float64_pytree(fpu: HsaParams) -> None:
    leaves, treedef = jax.tree_util.tree_flatten(fpu)
    assert len(leaves) == 30
    assert all(leaf.dtype == jnp.float64 for leaf in leaves)
    rebuilt = jax.tree_util.tree_unflatten(treedef, leaves)
    assert isinstance(rebuilt, HsaParams) and rebuilt.material == "fpu"
    with pytest.raises(dataclasses.FrozenInstanceError):
        fpu.l = jnp.float64(1.0)  # type: ignore[misc]
    # static fields are aux data: a different kappa rule is a different tree structure
    assert jax.tree_util.tree_structure(fpu.replace(kappa_rule="exp2023_shift")) != treedef
    # params as a traced argument
    assert float(jax.jit(lambda p: p.m_p)(fpu)) == pytest.approx(77.4565e-3, rel=1e-6)


def test_overrides_use_file_semantics_and_rest_strains(fpu: HsaParams) -> None:
    p = load_params("epu", sigma_a_eq=[1.05440951, 1.04468427])
    np.testing.assert_allclose(p.xi_eq, [0.0, 0.0, (1.05440951 + 1.04468427) / 2], rtol=1e-15)
    p = load_params("fpu", S_a_hat=[1.0, 2.0], kappa_rule="exp2023_shift")
    np.testing.assert_array_equal(p.S_a_hat, [2.0, 4.0])  # per physical rod -> doubled
    assert p.kappa_rule == "exp2023_shift"
    # sigma_ax,eq = mean(sigma_a_eq) - mean(roff kappa_b_eq) (model.md §5.4)
    p = fpu.replace(kappa_b_eq=jnp.array([1.0, 3.0]), sigma_a_eq=jnp.array([1.01, 1.03]))
    np.testing.assert_allclose(
        p.xi_eq, [2.0, 0.0, 1.02 - (-0.024 * 1.0 + 0.024 * 3.0) / 2], rtol=1e-15
    )


def test_replace_is_validated_and_keeps_stored_units(fpu: HsaParams) -> None:
    p = fpu.replace(m_pl=0.2, CoG_pl=[0.0, -0.0255])
    assert float(p.m_pl) == 0.2 and float(fpu.m_pl) == 0.0
    np.testing.assert_array_equal(p.S_a_hat, fpu.S_a_hat)  # replace() does not double again
    with pytest.raises(ParameterError, match="'l'"):
        fpu.replace(l=-0.059)
    with pytest.raises(ParameterError, match="'zeta_a'"):
        fpu.replace(zeta_a=[0.04, -1.0])
    with pytest.raises(ParameterError, match="'bogus'"):
        fpu.replace(bogus=1.0)
    with pytest.raises(ParameterError, match="'kappa_rule'"):
        fpu.replace(kappa_rule="later")
    with pytest.raises(ParameterError, match="'sigma_a_eq'"):
        load_params("fpu", sigma_a_eq=[1.05])


def test_unknown_packaged_name_or_missing_file() -> None:
    with pytest.raises(ParameterError, match="no such parameter file"):
        load_params("pla")
    with pytest.raises(ParameterError, match="nothere.yaml"):
        load_params(Path("/nonexistent/nothere.yaml"))


def _fpu_raw() -> dict:
    return yaml.safe_load((CONFIG_DIR / "fpu.yaml").read_text())


BAD_FILES = [
    ("unknown key", lambda d: d.update(S_x_hat=[1.0, 1.0]), "S_x_hat"),
    ("missing key", lambda d: d.pop("C_S_a"), "C_S_a"),
    ("missing material", lambda d: d.pop("material"), "material"),
    ("wrong shape", lambda d: d.update(roff=[-0.024, 0.0, 0.024]), "roff"),
    ("scalar for per-rod", lambda d: d.update(r_out=0.0127), "r_out"),
    ("list for scalar", lambda d: d.update(l=[0.059]), "'l'"),
    ("string", lambda d: d.update(S_a_hat="5.66"), "S_a_hat"),
    ("string inside list", lambda d: d.update(C_eps=[0.0098, "x"]), "C_eps"),
    ("bool", lambda d: d.update(m_pl=True), "m_pl"),
    ("null", lambda d: d.update(rho_p=None), "rho_p"),
    ("nan", lambda d: d.update(S_b_hat=[float("nan"), 1.0]), "S_b_hat"),
    ("inf", lambda d: d.update(g=[0.0, float("inf")]), "'g'"),
    ("zero length", lambda d: d.update(l=0.0), "'l'"),
    ("negative cap", lambda d: d.update(l_dc=-0.014), "l_dc"),
    ("zero radius", lambda d: d.update(r_in=[0.0, 0.01]), "r_in"),
    ("r_in >= r_out", lambda d: d.update(r_in=[0.0127, 0.0127]), "r_in"),
    (
        "negative platform size",
        lambda d: d.update(platform_size=[0.08, -0.012, 0.08]),
        "platform_size",
    ),
    ("negative density", lambda d: d.update(rho_r=[-798.38, 798.38]), "rho_r"),
    ("negative platform density", lambda d: d.update(rho_p=-925.0), "rho_p"),
    ("negative payload", lambda d: d.update(m_pl=-0.2), "m_pl"),
    ("zero phi_max", lambda d: d.update(phi_max=[0.0, 3.49]), "phi_max"),
    ("negative damping", lambda d: d.update(zeta_sh=[2e-4, -2e-4]), "zeta_sh"),
    ("bad handedness", lambda d: d.update(h=[1.0, 0.5]), "'h'"),
    ("non-positive sigma_a_eq", lambda d: d.update(sigma_a_eq=[1.0, 0.0]), "sigma_a_eq"),
    ("bad kappa rule", lambda d: d.update(kappa_rule="later"), "kappa_rule"),
]


@pytest.mark.parametrize("case, mutate, key", BAD_FILES, ids=[c[0] for c in BAD_FILES])
def test_bad_parameter_files_name_the_key_and_file(
    tmp_path: Path, case: str, mutate, key: str
) -> None:
    raw = _fpu_raw()
    mutate(raw)
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(raw))
    with pytest.raises(ParameterError) as info:
        load_params(path)
    assert key in str(info.value) and str(path) in str(info.value), str(info.value)


def test_yaml_syntax_and_top_level_type_errors(tmp_path: Path) -> None:
    path = tmp_path / "broken.yaml"
    path.write_text("l: [0.059\n")
    with pytest.raises(ParameterError, match="not valid YAML"):
        load_params(path)
    path.write_text("- 1\n- 2\n")
    with pytest.raises(ParameterError, match="mapping"):
        load_params(path)
    # a YAML 1.1 pitfall: "3e-5" without a dot is a string, and must be rejected, not silently
    # accepted
    raw = (
        (CONFIG_DIR / "fpu.yaml")
        .read_text()
        .replace("zeta_b: [3.0e-5, 3.0e-5]", "zeta_b: [3e-5, 3e-5]")
    )
    path.write_text(raw)
    with pytest.raises(ParameterError, match="zeta_b"):
        load_params(path)


def test_a_valid_custom_file_loads(tmp_path: Path) -> None:
    raw = _fpu_raw()
    raw.update(material="fpu_payload", m_pl=0.2, CoG_pl=[0.0, -0.0255], chiee_off=[0.0, 0.025, 0.0])
    path = tmp_path / "payload.yaml"
    path.write_text(yaml.safe_dump(raw))
    p = load_params(str(path))
    assert p.material == "fpu_payload" and float(p.m_pl) == 0.2
