"""The risk configuration's floor, digest, and the store that keeps the one in force with a version."""

from __future__ import annotations

import json
import stat

import msgpack
import numpy as np
import pytest
from foundation.strategies import risk_configs
from hypothesis import given
from pydantic import ValidationError

from riskfield.protocol import RiskConfig, RiskGroup, ade20k, decode, encode
from riskfield.protocol.risk import FREE_LABELS
from riskfield.services.runtime.risk_file import RiskFileError, RiskStore

WALL, PERSON, FLOOR, CHAIR = (ade20k.index(n) for n in ("wall", "person", "floor", "chair"))


def test_default_group_null_keeps_occupied_geometry_an_obstacle_of_the_lowest_group():
    risk = RiskConfig(groups=[RiskGroup(name="high", labels=[PERSON]), RiskGroup(name="low", labels=[CHAIR])],
                      default_group=None)
    lut = risk.label_to_group()
    assert lut[WALL] == 2 and lut[PERSON] == 1 and lut[CHAIR] == 2 and lut[FLOOR] == 0
    assert WALL in risk.below_floor() and FLOOR not in risk.below_floor()


def test_an_extra_free_label_stays_an_obstacle_and_a_free_surface_may_be_raised():
    risk = RiskConfig(free_labels=[*FREE_LABELS, WALL])
    assert risk.label_to_group()[WALL] == risk.group_id("low")
    raised = RiskConfig(groups=[RiskGroup(name="high", labels=[FLOOR])], default_group="high")
    assert raised.label_to_group()[FLOOR] == 1  # a group may make a free surface an obstacle


def test_the_defaults_are_above_the_floor():
    assert RiskConfig().below_floor() == []


def test_a_configuration_naming_no_obstacle_is_refused_also_on_the_wire():
    with pytest.raises(ValidationError, match="no obstacle labels"):
        RiskConfig(groups=[RiskGroup(name="high"), RiskGroup(name="low")], default_group=None)
    hostile = {"schema": "RiskConfig/1", "header": {"stamp_ns": 1, "frame_id": "map", "seq": 0},
               "groups": [{"name": "low", "labels": []}], "free_labels": [], "default_group": None}
    with pytest.raises(ValueError, match="no obstacle labels"):
        decode(msgpack.packb(hostile), RiskConfig)


@given(risk_configs())
def test_under_any_configuration_only_free_surfaces_can_be_free(risk):
    lut = risk.label_to_group()
    free = np.flatnonzero(lut == 0)
    assert np.isin(free, FREE_LABELS).all()
    assert lut.max() <= len(risk.groups)
    assert decode(encode(risk), RiskConfig).digest() == risk.digest()


def test_the_digest_is_of_the_content_not_the_header():
    a, b = RiskConfig(), RiskConfig()
    b.header.seq, b.header.stamp_ns = 7, 12345
    assert a.digest() == b.digest() and len(a.digest()) == 16
    assert RiskConfig(groups=[RiskGroup(name="low", margin=0.1)]).digest() != a.digest()


def test_the_store_versions_changes_and_keeps_them_across_a_restart(tmp_path):
    store = RiskStore(tmp_path / "state", "safety-filter")
    assert (store.version, store.digest) == (0, RiskConfig().digest())
    assert not store.commit(RiskConfig(), "test")  # the one in force: no new version
    wide = RiskConfig(groups=[RiskGroup(name="high", labels=[PERSON], margin=0.5), RiskGroup(name="low")])
    assert store.commit(wide, "test") and store.version == 1
    path = tmp_path / "state" / "risk-safety-filter.json"
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    again = RiskStore(tmp_path / "state", "safety-filter")
    assert (again.version, again.digest) == (1, wide.digest()) and again.risk.groups[0].margin == 0.5
    assert again.commit(RiskConfig(), "test") and again.version == 2  # back to the defaults is a change too
    assert RiskStore(tmp_path / "state", "mapping").version == 0  # one file per service
    assert [p.name for p in (tmp_path / "state").iterdir()] == ["risk-safety-filter.json"]  # no temporary left


def test_a_state_file_that_does_not_load_is_an_error_naming_it(tmp_path):
    path = tmp_path / "risk-mapping.json"
    path.write_text(json.dumps({"version": 3, "config": {"groups": [{"name": "a"}], "default_group": None}}))
    with pytest.raises(RiskFileError, match=r"risk-mapping\.json.*no obstacle labels"):
        RiskStore(tmp_path, "mapping")
    path.write_text("{not json")
    with pytest.raises(RiskFileError, match=r"risk-mapping\.json"):
        RiskStore(tmp_path, "mapping")


def test_without_a_state_dir_nothing_is_written(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    store = RiskStore(None, "safety-filter")
    assert store.commit(RiskConfig(groups=[RiskGroup(name="low", margin=0.2)]), "test") and store.version == 1
    assert list(tmp_path.iterdir()) == []
