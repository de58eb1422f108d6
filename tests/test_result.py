"""station/result.py: the typed result and its JSON (docs/result-schema.md, version 1)."""

from __future__ import annotations

import json
import re
from pathlib import Path

from result_builder import make_result, with_spec, with_steering
from station.records.vehicle_specs import load_vehicle_specs
from station.result import ANGLE_NAMES, STEERING_ANGLE_NAMES, Failure, Measurement, WarningFlag

ROOT = Path(__file__).resolve().parents[1]
SPECS = load_vehicle_specs(ROOT / "config" / "vehicles.yaml")


def _schema_keys() -> set[str]:
    """Every key the schema document's JSON example names."""
    doc = (ROOT / "docs" / "result-schema.md").read_text()
    example = doc.split("```json", 1)[1].split("```", 1)[0]
    return set(re.findall(r'"(\w+)"\s*:', example))


def _keys(d, out=None) -> set[str]:
    out = set() if out is None else out
    if isinstance(d, dict):
        for k, v in d.items():
            if k not in ("truth", "errors", "detections"):  # the simulator's and the detector's own
                _keys(v, out)
            out.add(k)
    elif isinstance(d, list):
        for v in d:
            _keys(v, out)
    return out


def test_every_key_of_the_json_is_in_the_schema_document():
    r = with_spec(with_steering(make_result(3), {"FL": 3.0, "FR": 3.1}, {"FL": 12.0, "FR": 12.1}),
                  SPECS["toyota-echo-2003"])
    r.warn("pair FR (cam1, cam2): epipolar residual 0.9 px", WarningFlag("drift", "FR"))
    r.warning_flags.append(WarningFlag("centreline", "FL", because_of=["FR"]))
    r.warning_flags.append(WarningFlag("focus", "RL", camera="cam5"))
    r.method, r.runout_compensated = "circle", True
    r.wheels["FL"].runout_deg, r.wheels["FL"].runout_phase_deg, r.wheels["FL"].runout_mm = 0.1, 20.0, 0.8
    keys = _keys(r.to_json()) - {w for w in ("FL", "FR", "RL", "RR", "front", "rear", "left", "right")} - set(ANGLE_NAMES + STEERING_ANGLE_NAMES)
    assert "caster" in r.to_json()["wheels"]["FL"]["pass"] and "steering" in r.to_json()
    assert keys <= _schema_keys() | {"overall", "because_of", "camera", "pass"}, keys - _schema_keys()


def test_json_round_trip_is_exact():
    """A stored cycle read back (the history, the report) gives the same JSON again."""
    valid = with_spec(make_result(1), SPECS["toyota-echo-2003"])
    valid.add_truth({"wheels": {w: {"toe_deg": 0.0, "camber_deg": 0.0} for w in ("FL", "FR", "RL", "RR")},
                     "total_toe_front_deg": 0.0, "total_toe_rear_deg": 0.0, "thrust_deg": 0.0})
    valid.warn("RR: toe uncertain", WarningFlag("uncertain", "RR"))
    failed = make_result(2, valid=False)
    for r in (valid, failed, Measurement(station="bare")):
        d = json.loads(json.dumps(r.to_json()))
        again = Measurement.from_json(d).to_json()
        assert again == d and list(again) == list(d)


def test_a_valid_result_carries_every_angle_and_an_invalid_one_none():
    r = make_result(4)
    d = r.to_json()
    assert d["valid"] and d["failure"] is None and set(d["wheels"]) == {"FL", "FR", "RL", "RR"}
    assert "toe_thrust_deg" in d["wheels"]["FL"] and "toe_thrust_deg" not in d["wheels"]["RL"]
    assert all(isinstance(r.angle(n), float) for n in ANGLE_NAMES)
    bad = make_result(4, valid=False).to_json()
    assert not bad["valid"] and bad["wheels"] == {} and bad["axles"] == {} and bad["thrust_deg"] is None
    assert bad["failure"] == {"code": 401, "message": "RR cam7: no closed rim contour", "hint": None}
    assert Measurement.from_json(bad).angle("FL.toe") is None


def test_failure_and_flags_serialise_as_the_schema_says():
    assert Failure(401, "m", "h", "RL", "cam5").to_json() == {"code": 401, "wheel": "RL", "camera": "cam5",
                                                              "message": "m", "hint": "h"}
    assert WarningFlag("drift", "FR").to_json() == {"kind": "drift", "wheel": "FR"}
    assert WarningFlag("exposure", "RL", camera="cam6").to_json() == {"kind": "exposure", "wheel": "RL",
                                                                      "camera": "cam6"}
    flag = WarningFlag("centreline", "FL", because_of=["RR"], text="FL: toe in doubt")
    assert flag.to_json() == {"kind": "centreline", "wheel": "FL", "because_of": ["RR"]}  # no text
    assert flag == WarningFlag("centreline", "FL", because_of=["RR"])  # the sentence is not compared


def test_verdicts_appear_per_angle_and_per_wheel():
    r = with_spec(make_result(0, toe={"FL": 0.05, "FR": 0.05, "RL": 0.0, "RR": 0.0}), SPECS["dodge-caravan-2007"])
    d = r.to_json()
    assert d["pass"] == r.verdicts and d["vehicle_spec"] == "dodge-caravan-2007"
    for w in ("FL", "FR", "RL", "RR"):
        assert d["wheels"][w]["pass"] == {"toe": r.verdicts[f"{w}.toe"], "camber": r.verdicts[f"{w}.camber"]}
