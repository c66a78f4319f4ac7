"""The one risk-file loader, watcher and hot reload, shared by mapping and the safety filter."""

from __future__ import annotations

import logging
import os
import time

import pytest

from riskfield.protocol import RiskConfig, ade20k, decode, encode
from riskfield.services.runtime import risk_file
from riskfield.services.runtime.risk_file import RiskFileError, RiskFileReloader, RiskFileWatcher, load_risk_file

EXAMPLE = risk_file.__doc__.split("::\n", 1)[1].split("\n\n", 1)[0]  # the documented example, verbatim

RISK_YAML = """
risk:
  groups:
    - {name: high, labels: [person, animal], margin: 0.2, alpha: 0.5, alpha1: 1.0, alpha2: 0.2}
    - {name: low, labels: [wall, 119], margin: 0.0, alpha: 2.0}
  default_group: low
"""


def _touch(path, text: str, bump: int) -> None:
    """Write and move the modification time forward, so a same-size rewrite is seen too."""
    path.write_text(text)
    os.utime(path, ns=(time.time_ns(), time.time_ns() + bump * 10**9))


def test_documented_example_validates_for_mapping_and_the_filter(tmp_path):
    from riskfield.services.mapping.config import MapperConfig
    from riskfield.services.mapping.mapper import Mapper
    from riskfield.services.safety_filter.config import FilterConfig
    from riskfield.services.safety_filter.filter import SafetyFilter

    assert "person, animal" in EXAMPLE
    path = tmp_path / "risk.yaml"
    path.write_text(EXAMPLE)
    risk = load_risk_file(path)
    assert risk.groups[0].labels == [ade20k.index("person"), ade20k.index("animal")]
    mapper = Mapper(MapperConfig(voxel_size=0.1, half_extent=(1.0, 1.0, 1.0)), risk)  # what mapping applies
    assert mapper.label_to_group[ade20k.index("person")] == 1
    assert mapper.label_to_group[ade20k.index("wall")] == 2
    SafetyFilter(FilterConfig(), risk).set_risk(risk)  # what the filter applies


def test_risk_file_accepts_class_names_and_indices(tmp_path):
    path = tmp_path / "risk.yaml"
    path.write_text(RISK_YAML)
    risk = load_risk_file(path)
    assert risk.group_names == ["high", "low"]
    assert risk.groups[0].labels == [ade20k.index("person"), ade20k.index("animal")]
    assert risk.groups[1].labels == [0, 119]
    decode(encode(risk), RiskConfig)


def test_a_valid_file_may_omit_optional_keys(tmp_path):
    path = tmp_path / "risk.yaml"
    path.write_text("groups: [{name: high, labels: [person]}]\ndefault_group: high\n")
    risk = load_risk_file(path)
    assert risk.groups[0].margin == 0.0 and risk.free_labels == RiskConfig().free_labels


@pytest.mark.parametrize(("text", "words"), [
    ("", "empty"),
    ("# only a comment\n", "empty"),
    ("groups: [{name: a, labels: [not a class]}]", "not an ADE20K class name"),
    ("groups: [{name: a, labels: [persn]}]", "did you mean 'person'"),
    ("groups: []", "groups"),
    ("- 1", "mapping"),
    ("groups: [{", "risk file"),
    ("groups: [{name: high, labels: [person], marign: 0.3}]",
     "unknown key 'marign' in risk group 0; did you mean 'margin'"),
    ("grups: [{name: high}]", "unknown key 'grups' in the risk configuration; did you mean 'groups'"),
    # a gain no platform can honour near contact (protocol.risk.MAX_GAIN)
    ("groups: [{name: high, labels: [person], alpha: 1000}]", r"alpha(.|\n)*less than or equal to 20"),
])
def test_bad_risk_files_raise_one_clear_error(tmp_path, text, words):
    path = tmp_path / "risk.yaml"
    path.write_text(text)
    with pytest.raises(RiskFileError, match=words) as info:
        load_risk_file(path)
    assert str(path) in str(info.value)


def test_watcher_reports_each_change_once(tmp_path):
    path = tmp_path / "risk.toml"
    path.write_text('default_group = "a"\n[[groups]]\nname = "a"\nalpha = 1.0\n')
    w = RiskFileWatcher(path)
    first = w.poll()
    assert first is not None and first.groups[0].alpha == 1.0
    assert w.poll() is None
    _touch(path, 'default_group = "a"\n[[groups]]\nname = "a"\nalpha = 2.5\n', 1)
    second = w.poll()
    assert second is not None and second.groups[0].alpha == 2.5
    assert RiskFileWatcher(tmp_path / "missing.yaml").poll() is None


GOOD = "groups: [{name: high, labels: [person], margin: 0.30}, {name: low}]\ndefault_group: low\n"
BAD = {
    "empty": "",
    "truncated": "groups: [{name: high, labels: [per",
    "invalid": "groups: [{name: high, margin: -1}]\n",
    "unknown keys": "groups: [{name: high, labels: [person], margins: 0.30}]\n",
    "refused by the core": "groups: [{name: x}]\ndefault_group: x\n",
}


@pytest.mark.parametrize("kind", list(BAD))
def test_hot_reload_keeps_the_previous_configuration(tmp_path, caplog, kind):
    path = tmp_path / "risk.yaml"
    path.write_text(GOOD)
    applied: list[RiskConfig] = []

    def apply(risk: RiskConfig) -> None:
        if risk.group_names == ["x"]:
            raise ValueError("unknown_group 'low' is not a risk group of ['x']")
        applied.append(risk)

    stats: dict[str, float] = {}
    r = RiskFileReloader(path, apply, logging.getLogger("test.risk"), stats)
    assert r.initial.groups[0].margin == 0.30 and stats == {"risk_reloads": 0, "risk_errors": 0}
    _touch(path, BAD[kind], 1)
    with caplog.at_level(logging.INFO, "test.risk"):
        assert r.poll() is None
        assert r.poll() is None  # the same bad file is reported once, not on every poll
    assert applied == [] and stats == {"risk_reloads": 0, "risk_errors": 1}
    errors = [rec for rec in caplog.records if rec.levelno == logging.ERROR]
    assert len(errors) == 1 and "keeping the configuration in force" in errors[0].getMessage()
    _touch(path, GOOD.replace("0.30", "0.35"), 2)
    assert r.poll() is not None
    assert applied[-1].groups[0].margin == 0.35 and stats["risk_reloads"] == 1


def test_a_missing_file_at_start_is_an_error(tmp_path):
    with pytest.raises(FileNotFoundError):
        RiskFileReloader(tmp_path / "nope.yaml", lambda r: None, logging.getLogger("t"), {})
