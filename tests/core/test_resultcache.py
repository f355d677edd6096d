"""hsa_core.resultcache: start-up results kept on disk, keyed by their inputs and the core's
source."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hsa_core import resultcache
from hsa_core.model.params import load_params
from hsa_core.task.planning import Planner


class Counting:
    """A computation that counts its calls."""

    def __init__(self, value: float) -> None:
        self.calls, self.value = 0, value

    def __call__(self) -> dict[str, np.ndarray]:
        self.calls += 1
        return {"x": np.array([self.value, 2.0 * self.value])}


@pytest.fixture
def cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.setenv("HSA_JAX_CACHE_DIR", str(tmp_path))
    return tmp_path


def test_second_call_reads_the_entry(cache: Path) -> None:
    first = Counting(1.5)
    assert resultcache.cached("t", (np.arange(3),), first)["x"].tolist() == [1.5, 3.0]
    again = Counting(99.0)  # a different answer would show if it ran
    assert resultcache.cached("t", (np.arange(3),), again)["x"].tolist() == [1.5, 3.0]
    assert (first.calls, again.calls) == (1, 0)
    assert len(list((cache / "results").glob("t-*.npz"))) == 1


def test_other_inputs_name_or_dtype_compute_afresh(cache: Path) -> None:
    resultcache.cached("t", (np.arange(3),), Counting(1.0))
    for name, inputs in (
        ("t", (np.arange(4),)),
        ("u", (np.arange(3),)),
        ("t", (np.arange(3.0),)),
        ("t", (load_params("fpu"),)),
    ):
        fresh = Counting(2.0)
        assert resultcache.cached(name, inputs, fresh)["x"].tolist() == [2.0, 4.0]
        assert fresh.calls == 1


def test_parameter_sets_differ_in_their_key() -> None:
    fpu = load_params("fpu")
    assert resultcache.key("r", fpu) == resultcache.key("r", load_params("fpu"))
    assert resultcache.key("r", fpu) != resultcache.key("r", load_params("epu"))
    assert resultcache.key("r", fpu) != resultcache.key(
        "r", fpu.replace(kappa_rule="exp2023_shift")
    )


def test_unreadable_entry_is_recomputed(cache: Path) -> None:
    resultcache.cached("t", (1,), Counting(1.0))
    (entry,) = (cache / "results").glob("t-*.npz")
    entry.write_bytes(b"not an npz")
    fresh = Counting(3.0)
    assert resultcache.cached("t", (1,), fresh)["x"].tolist() == [3.0, 6.0] and fresh.calls == 1


def test_empty_setting_disables_the_cache(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("HSA_JAX_CACHE_DIR", "")
    counting = Counting(1.0)
    resultcache.cached("t", (1,), counting)
    resultcache.cached("t", (1,), counting)
    assert counting.calls == 2


def test_planner_region_is_the_same_from_the_cache(
    cache: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A planner built on a cached region holds the very polygon a planner without cache
    computes."""
    params = load_params("fpu")
    monkeypatch.setenv("HSA_JAX_CACHE_DIR", "")
    computed = Planner(params, "static")._region.boundary
    monkeypatch.setenv("HSA_JAX_CACHE_DIR", str(cache))
    Planner(params, "static")  # fills the entry
    assert len(list((cache / "results").glob("reachability-*.npz"))) == 1
    np.testing.assert_array_equal(Planner(params, "static")._region.boundary, computed)


def test_world_starts_from_the_same_state_from_the_cache(
    cache: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The world's hanging-at-rest start state read from the cache is the one it computes without a
    cache."""
    from hsa_core.model.wiring import load_wiring
    from hsa_core.sim.disturbance import DisturbanceModel
    from hsa_core.sim.world import World

    params = load_params("fpu")
    motor_map = load_wiring().motor_map(params)
    monkeypatch.setenv("HSA_JAX_CACHE_DIR", "")
    computed = np.asarray(World(params, DisturbanceModel(), motor_map).x)
    monkeypatch.setenv("HSA_JAX_CACHE_DIR", str(cache))
    World(params, DisturbanceModel(), motor_map)  # fills the entry
    assert len(list((cache / "results").glob("hanging_at_rest-*.npz"))) == 1
    np.testing.assert_array_equal(
        np.asarray(World(params, DisturbanceModel(), motor_map).x), computed
    )
    assert computed[2] != 0.0 and np.all(computed[3:] == 0.0)  # hanging under gravity, at rest
