"""Vehicle specs: the shipped file loads, bad files name file/vehicle/key, pass/fail is right."""

from pathlib import Path

import pytest
import yaml

from result_builder import make_result, with_steering
from station.errors import ConfigError
from station.records.vehicle_specs import apply_spec, evaluate, get_spec, load_vehicle_specs
from station.result import ANGLE_NAMES, STEERING_ANGLE_NAMES

SHIPPED = Path(__file__).resolve().parent.parent / "config" / "vehicles.yaml"


@pytest.fixture(scope="module")
def specs():
    return load_vehicle_specs(SHIPPED)


def test_shipped_file_has_the_primer_figures(specs):
    assert len(specs) >= 3
    caravan = specs["dodge-caravan-2007"]
    assert caravan.angles["FL.camber"].low_deg == pytest.approx(-0.30)
    assert caravan.angles["FR.camber"].high_deg == pytest.approx(0.50)
    assert caravan.angles["front.total_toe"].nominal_deg == pytest.approx(0.10)
    assert caravan.angles["thrust"].tolerance_deg == pytest.approx(0.30)
    echo = specs["toyota-echo-2003"]
    assert echo.angles["FL.camber"].nominal_deg == pytest.approx(-0.60)
    assert echo.angles["FL.camber"].tolerance_deg == pytest.approx(0.76)
    assert echo.angles["thrust"] is None  # the manual has no figure: not checked
    for spec in specs.values():
        assert spec.source
        assert set(spec.angles) == set(ANGLE_NAMES + STEERING_ANGLE_NAMES)
        for a in spec.angles.values():
            assert a is None or a.source


def _write(tmp_path, mutate):
    raw = yaml.safe_load(SHIPPED.read_text())
    mutate(raw)
    p = tmp_path / "vehicles.yaml"
    p.write_text(yaml.safe_dump(raw))
    return p


def test_missing_tolerance_names_file_vehicle_and_key(tmp_path):
    p = _write(tmp_path, lambda r: r["vehicles"]["toyota-echo-2003"]["angles"]["rear.camber"].pop("tolerance_deg"))
    with pytest.raises(ConfigError) as e:
        load_vehicle_specs(p)
    msg = str(e.value)
    assert str(p) in msg and "toyota-echo-2003" in msg and "rear.camber.tolerance_deg" in msg


@pytest.mark.parametrize("mutate, needle", [
    (lambda r: r["vehicles"]["dodge-caravan-2007"]["angles"].pop("thrust"), "angles.thrust: missing"),
    (lambda r: r["vehicles"]["dodge-caravan-2007"]["angles"]["front.camber"].update(tolerance_deg=-0.1), "tolerance_deg"),
    (lambda r: r["vehicles"]["dodge-caravan-2007"]["angles"]["front.camber"].update(nominal_deg="0.1"), "nominal_deg"),
    (lambda r: r["vehicles"]["dodge-caravan-2007"]["angles"].update({"front.cambre": None}), "did you mean 'front.camber'"),
    (lambda r: r["vehicles"]["dodge-caravan-2007"].pop("source"), "source"),
    (lambda r: r.update(version=2), "version"),
    (lambda r: r["vehicles"]["dodge-caravan-2007"]["angles"]["rear.toe"].update(nominal_deg=10**400),
     "angles.rear.toe.nominal_deg: expected a number of degrees"),
])
def test_bad_files_are_config_errors(tmp_path, mutate, needle):
    p = _write(tmp_path, mutate)
    with pytest.raises(ConfigError, match=needle.replace("(", r"\(").replace(".", r"\.")):
        load_vehicle_specs(p)


def test_unreadable_files(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        load_vehicle_specs(tmp_path / "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("version: 1\nvehicles: [unclosed\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_vehicle_specs(bad)


def test_unknown_vehicle_suggests(specs):
    with pytest.raises(ConfigError, match="did you mean dodge-caravan-2007"):
        get_spec(specs, "dodge-caravan-2008")


def test_evaluate_boundaries_and_overall(specs):
    caravan = specs["dodge-caravan-2007"]
    # front camber window -0.30..+0.50; individual front toe 0.05 +/- 0.10; total 0.10 +/- 0.20
    r = make_result(0, toe={"FL": 0.05, "FR": 0.05, "RL": 0.0, "RR": 0.0},
                    camber={"FL": 0.50, "FR": -0.30, "RL": 0.0, "RR": 0.0})
    v = evaluate(r, caravan)
    assert v["FL.camber"] is True and v["FR.camber"] is True  # exactly on the limits
    assert v["overall"] is True
    r2 = make_result(0, toe={"FL": 0.05, "FR": 0.05, "RL": 0.0, "RR": 0.0},
                     camber={"FL": 0.51, "FR": 0.0, "RL": 0.0, "RR": 0.0})
    v2 = evaluate(r2, caravan)
    assert v2["FL.camber"] is False and v2["FR.camber"] is True and v2["overall"] is False
    # thrust from rear toe: (RL - RR)/2 = 0.35 > 0.30 fails, and the rear total toe still passes
    r3 = make_result(0, toe={"FL": 0.05, "FR": 0.05, "RL": 0.35, "RR": -0.35},
                     camber={w: 0.0 for w in ("FL", "FR", "RL", "RR")})
    v3 = evaluate(r3, caravan)
    assert v3["thrust"] is False and v3["rear.total_toe"] is True and v3["RL.toe"] is False


def test_missing_figure_is_not_checked_and_invalid_never_passes(specs):
    echo = specs["toyota-echo-2003"]
    r = make_result(0, toe={"FL": 0.0, "FR": 0.0, "RL": 1.0, "RR": -0.65},
                    camber={"FL": -0.6, "FR": -0.6, "RL": -0.95, "RR": -0.95})
    v = evaluate(r, echo)
    assert v["thrust"] is None  # 0.825 deg of thrust, but no figure to check against
    assert v["RL.toe"] is False
    bad = make_result(0, valid=False)
    assert evaluate(bad, echo)["overall"] is False


def test_apply_spec_writes_schema_keys(specs):
    r = make_result(3, toe={"FL": 0.05, "FR": 0.05, "RL": 0.0, "RR": 0.0},
                    camber={"FL": 0.1, "FR": 0.1, "RL": 0.0, "RR": 0.0})
    apply_spec(r, specs["dodge-caravan-2007"])
    assert r.verdicts["overall"] is True
    assert r.to_json()["wheels"]["FL"]["pass"] == {"toe": True, "camber": True}
    assert r.vehicle_spec == "dodge-caravan-2007"


def test_caster_and_sai_are_judged_on_a_steering_sweep_only(specs):
    echo = specs["toyota-echo-2003"]  # caster 2.00 +/- 0.75, SAI 10.08 +/- 0.75, included angle: no figure
    assert echo.angles["FR.sai"].nominal_deg == pytest.approx(10.08) and echo.angles["FL.included_angle"] is None
    plain = make_result(0, camber={"FL": -0.6, "FR": -0.6})
    verdict = evaluate(plain, echo)
    assert not set(STEERING_ANGLE_NAMES) & set(verdict)  # a plain measurement has no caster to judge
    swept = with_steering(make_result(0, camber={"FL": -0.6, "FR": -0.6}), {"FL": 2.74, "FR": 2.76},
                          {"FL": 9.34, "FR": 10.0})
    verdict = evaluate(swept, echo)
    assert verdict["FL.caster"] is True and verdict["FR.caster"] is False  # 2.76 > 2.00 + 0.75
    assert verdict["FL.sai"] is True and verdict["FL.included_angle"] is None
    assert verdict["overall"] is (verdict["FR.caster"] and all(v is not False for v in verdict.values()))
    apply_spec(swept, echo)
    fl = swept.to_json()["wheels"]["FL"]["pass"]
    assert fl["caster"] is True and fl["sai"] is True and fl["included_angle"] is None
    assert "caster" not in swept.to_json()["wheels"]["RL"]["pass"]


def test_steering_keys_are_optional_and_checked(tmp_path):
    def drop(r):
        for k in ("front.caster", "front.sai", "front.included_angle"):
            r["vehicles"]["toyota-echo-2003"]["angles"].pop(k, None)
    assert load_vehicle_specs(_write(tmp_path, drop))["toyota-echo-2003"].angles["FL.caster"] is None

    def typo(r):
        r["vehicles"]["toyota-echo-2003"]["angles"]["front.castor"] = {"nominal_deg": 3, "tolerance_deg": 1,
                                                                         "source": "x"}
    with pytest.raises(ConfigError, match="front.castor.*did you mean 'front.caster'"):
        load_vehicle_specs(_write(tmp_path, typo))

    def implausible(r):
        r["vehicles"]["toyota-echo-2003"]["angles"]["front.sai"]["nominal_deg"] = 40
    with pytest.raises(ConfigError, match="front.sai.nominal_deg"):
        load_vehicle_specs(_write(tmp_path, implausible))
