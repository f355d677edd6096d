"""hsa_core.analysis.live: the scene throttle, the JSON payloads of the live view (no NaN, no null),
the diagnostics table, progress."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import pytest

from hsa_core.analysis import live


def test_throttle_lets_one_event_per_period_through_and_restarts_after_a_clock_reset() -> None:
    throttle = live.Throttle(25.0)  # 40 ms
    times = [i * 5_000_000 for i in range(200)]  # 1 s of a 200 Hz stream [ns]
    passed = [t for t in times if throttle.due(t)]
    assert passed == times[::8]  # every 40 ms exactly: 25 per second
    assert throttle.due(0)  # time went back (restarted simulation): accepted at once, not after 1 s
    assert not throttle.due(20_000_000)
    throttle.rate = 5.0
    assert not throttle.due(199_999_999) and throttle.due(200_000_000)
    with pytest.raises(ValueError, match="rate"):
        live.Throttle(0.0)


def test_non_finite_numbers_are_left_out_so_the_json_stays_valid_and_single_typed() -> None:
    sample = live.actuation_sample(
        [math.nan, 0.5], [math.inf, 0.6], [0.7, 0.9], [0.0, 0.0], [3.1, 3.1], True
    )
    text = json.dumps(sample, allow_nan=False)  # raises on NaN
    assert "null" not in text and "phi_cmd" not in sample and "phi_unsat" not in sample
    assert sample["phi_ss"] == [0.7, 0.9] and sample["saturated"] is True
    assert live.phi_present_sample([math.nan, 0.2]) == {} and live.phi_present_sample(
        [0.1, 0.2]
    ) == {"phi": [0.1, 0.2]}
    assert live.finite({"a": {"x": None, "y": 1.0}, "b": None, "c": [1.0], "d": [None]}) == {
        "a": {"y": 1.0},
        "c": [1.0],
    }


def test_tracking_error_is_reference_minus_measurement() -> None:
    sample = live.tracking_sample([0.003, 0.110], [0.0, 0.114])
    assert sample["e"] == {"x": pytest.approx(-0.003), "y": pytest.approx(0.004)}
    assert sample["e_norm"] == pytest.approx(0.005)
    assert sample["p_ee"] == {"x": 0.003, "y": 0.110} and sample["p_des"] == {"x": 0.0, "y": 0.114}
    blind = live.tracking_sample([math.nan, 0.1], [0.0, 0.1])
    assert "e_norm" not in blind and blind["p_ee"] == {"y": 0.1} and blind["e"] == {"y": 0.0}


def test_configuration_sample_names_the_components() -> None:
    sample = live.configuration_sample([1.0, 0.01, 0.2], [2.0, 0.02, 0.3])
    assert sample == {
        "q": {"kappa_be": 1.0, "sigma_sh": 0.01, "sigma_ax": 0.2},
        "q_des": {"kappa_be": 2.0, "sigma_sh": 0.02, "sigma_ax": 0.3},
    }


def test_diagnostics_table_keeps_the_newest_status_and_marks_silent_ones_stale() -> None:
    table = live.DiagnosticsTable(stale_after=5.0)
    table.update("b: bus", 0, "ok", now=0.0)
    table.update("a: law", 1, "saturated", now=0.0)
    table.update("a: law", 0, "tracking", now=4.0)
    snap = table.snapshot(now=6.0)
    assert [r["name"] for r in snap["statuses"]] == ["a: law", "b: bus"]
    law, bus = snap["statuses"]
    assert (law["level_name"], law["message"], law["age"]) == ("OK", "tracking", 2.0)
    assert (bus["level_name"], bus["message"]) == ("STALE", "ok")  # 6 s without a report
    assert snap["worst"] == 3 and snap["worst_name"] == "STALE"
    assert snap["counts"] == {"OK": 1, "WARN": 0, "ERROR": 0, "STALE": 1}
    assert live.DiagnosticsTable(1.0).snapshot(0.0)["worst_name"] == "OK"


def test_progress_line_from_the_sequencer_status_and_the_controller() -> None:
    status = json.dumps(
        {
            "state": "running",
            "trajectory": "steps",
            "index": 2,
            "setpoint_index": 2,
            "length": 11,
            "finished": False,
            "failures": 1,
        }
    )
    p = live.progress(status, 2, 0.00125)
    assert (p["step"], p["steps"], p["controller_state"], p["failures"]) == (3, 11, "tracking", 1)
    assert p["text"] == "step 3/11 · tracking · ‖e‖ 1.25 mm · 1 failed"
    done = json.dumps({"setpoint_index": 10, "length": 11, "finished": True, "failures": 0})
    assert live.progress(done, 3, None)["text"] == "step 11/11 · holding (stale) · finished"
    assert (
        live.progress(None, None, None)["text"]
        == "no sequencer status yet · no controller_info yet"
    )
    assert "e_norm" not in live.progress(None, None, None)
    assert live.progress("not json", 7, None)["text"] == "no sequencer status yet · state 7"
    waiting = json.dumps({"setpoint_index": -1, "length": 11})
    assert live.progress(waiting, 0, None)["text"] == "no setpoint yet · waiting for setpoint"


def test_json_schema_describes_the_payload_with_one_type_per_field() -> None:
    schema = live.json_schema("hsa_live.Tracking", live.tracking_sample([0.0, 0.1], [0.0, 0.1]))
    assert schema["title"] == "hsa_live.Tracking" and schema["type"] == "object"
    # a string: Foxglove-family viewers
    assert schema["properties"]["p_ee"]["properties"]["x"]["type"] == "number"
    actuation = live.json_schema(
        "a", live.actuation_sample([0, 0], [0, 0], [0, 0], [0, 0], [1, 1], False)
    )
    assert actuation["properties"]["phi_cmd"] == {"type": "array", "items": {"type": "number"}}
    assert actuation["properties"]["saturated"] == {"type": "boolean"}


def test_every_controller_state_of_the_message_definition_has_its_name() -> None:
    definition = Path(__file__).parents[2] / "hsa_msgs" / "msg" / "ControllerInfo.msg"
    codes = {
        int(m[2]): m[1] for m in re.finditer(r"uint8 (STATE_\w+) = (\d+)", definition.read_text())
    }
    assert set(codes) == set(range(len(live.CONTROLLER_STATES)))
    assert (
        live.controller_state_name(max(codes)) == "driver torque off"
        and codes[max(codes)] == "STATE_TORQUE_OFF"
    )
