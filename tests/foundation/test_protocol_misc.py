"""Keys, ADE20K names, risk configuration, JSON Schema export, and the protocol's light dependencies."""

from __future__ import annotations

import json
import subprocess
import sys

import jsonschema
import numpy as np
import pytest

from riskfield.protocol import REGISTRY, TOPICS, Keys, RiskConfig, RiskGroup, ade20k
from riskfield.protocol.keys import QOS, ROUTES, base_of, qos_of, source_of
from riskfield.protocol.schema import export, json_schemas


def test_keys_follow_the_contract():
    k = Keys()
    assert k.esdf == "rf/limo1/map/esdf"
    assert k.esdf_query == "rf/limo1/map/esdf/query"
    assert k.cmd_safe == "rf/limo1/cmd/safe"
    assert k.alive("safety-filter") == "rf/limo1/alive/safety-filter"
    k2 = Keys(robot="drone7", prefix="site1/rf")
    assert k2.state == "site1/rf/drone7/state"
    assert k2.relative("site1/rf/drone7/cmd/ref") == "cmd/ref"
    assert k2.relative("site1/rf/other/cmd/ref") is None
    assert set(TOPICS) >= {"camera/image", "perception/frame", "map/esdf", "map/esdf/query", "state", "cmd/ref",
                           "cmd/safe", "safety/status", "nav/goal"}


def test_each_source_has_a_key_of_its_own_that_maps_back_to_the_contract_key():
    k = Keys()
    assert k.cmd_ref_of("joystick") == "rf/limo1/cmd/ref/joystick"
    assert k.cmd_lock_of("ros2/teleop") == "rf/limo1/cmd/lock/ros2/teleop"
    for rel, base, source in (("cmd/ref/joystick", "cmd/ref", "joystick"), ("cmd/ref/ros2/nav", "cmd/ref", "ros2/nav"),
                              ("cmd/ref", "cmd/ref", None), ("cmd/lock/operator", "cmd/lock", "operator"),
                              ("cmd/refx", "cmd/refx", None), ("map/esdf", "map/esdf", None)):
        assert (base_of(rel), source_of(rel)) == (base, source)
    assert qos_of("cmd/ref/joystick") == QOS["cmd/ref"]
    for bad in ("", "a*", "$x", "a//b", "a b"):
        with pytest.raises(ValueError):
            k.cmd_ref_of(bad)
    # every source role puts only its own key, and the plain key is put by no role
    assert ROUTES["cmd/ref"].producers == () and ROUTES["cmd/lock"].producers == ()
    assert ROUTES["cmd/ref/joystick"].producers == ("joystick",)


@pytest.mark.parametrize("robot", ["", "a/b", "r*", "r?x", "$x", "a b"])
def test_keys_reject_robot_ids_that_break_key_expressions(robot):
    with pytest.raises(ValueError):
        Keys(robot=robot)


def test_ade20k_indices_used_by_the_paper():
    assert ade20k.NUM_CLASSES == 150
    assert ade20k.index("person") == 12 and ade20k.index("ball") == 119 and ade20k.index("animal") == 126
    assert ade20k.CLASSES[:4] == ("wall", "building", "sky", "floor")
    with pytest.raises(KeyError, match="not an ADE20K class"):
        ade20k.index("unicorn")


def test_default_risk_config_matches_design():
    cfg = RiskConfig()
    lut = cfg.label_to_group()
    gid = {n: cfg.group_id(n) for n in ("high", "mid", "low")}
    assert lut[ade20k.index("person")] == gid["high"] and lut[ade20k.index("animal")] == gid["high"]
    assert lut[ade20k.index("ball")] == gid["low"] and lut[ade20k.index("wall")] == gid["low"]
    assert lut[ade20k.index("floor")] == 0 and lut[ade20k.index("ceiling")] == 0
    assert lut[ade20k.index("chair")] == gid["mid"]
    assert lut[ade20k.index("vase") + 1000] == gid["low"]  # unlisted labels are low-risk obstacles
    np.testing.assert_allclose(cfg.margins(), [0.0, 0.15, 0.05, 0.0])
    high, low = cfg.group(gid["high"]), cfg.group(gid["low"])
    assert high.alpha < low.alpha  # higher risk brakes earlier


def test_risk_config_rejects_inconsistent_groups():
    with pytest.raises(ValueError, match="unique"):
        RiskConfig(groups=[RiskGroup(name="a"), RiskGroup(name="a")])
    with pytest.raises(ValueError, match="in groups"):
        RiskConfig(groups=[RiskGroup(name="a", labels=[1]), RiskGroup(name="b", labels=[1])], default_group=None)
    with pytest.raises(ValueError, match="default_group"):
        RiskConfig(groups=[RiskGroup(name="a")], default_group="zzz")
    free = RiskConfig(groups=[RiskGroup(name="a", labels=[5])], default_group=None).label_to_group()
    assert free[5] == 1 and free[6] == 0


def test_json_schemas_are_valid_and_complete(tmp_path):
    paths = export(tmp_path)
    assert {p.name for p in paths} == {f"{s.split('/')[0]}.schema.json" for s in REGISTRY}
    for name, js in json_schemas().items():
        jsonschema.Draft202012Validator.check_schema(js)
        cls = REGISTRY[f"{name}/1"]
        assert js["properties"]["schema"] == {"const": cls.SCHEMA}
        assert "schema" in js["required"] and "header" in js["required"]
        assert set(cls.model_fields) <= set(js["properties"])
    esdf = json.loads((tmp_path / "EsdfGrid.schema.json").read_text())
    dist = esdf["properties"]["distance"]
    assert dist["properties"]["dtype"] == {"const": "<f4"} and dist["properties"]["shape"]["minItems"] == 3
    assert esdf["properties"]["risk_group"]["properties"]["dtype"] == {"const": "|u1"}


def test_json_schema_accepts_a_message_with_binary_as_text():
    from riskfield.protocol import VelocityCommand, to_map

    js = json_schemas()["VelocityCommand"]
    jsonschema.validate(to_map(VelocityCommand(linear=(1, 0, 0), angular=(0, 0, 0), source="x")), js)
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate({"schema": "VelocityCommand/1", "header": {}, "linear": [0, 0]}, js)


def test_protocol_imports_only_numpy_pydantic_msgpack():
    code = (
        "import sys, riskfield.protocol as p; "
        "heavy = {'zenoh', 'typer', 'rich', 'yaml', 'pydantic_settings', 'scipy', 'open3d', 'torch', 'osqp'}; "
        "print(sorted(m for m in sys.modules if m.split('.')[0] in heavy))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == "[]"
