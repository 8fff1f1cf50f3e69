"""Campaign files: the shipped ones plan, broken ones and bad arm overrides fail before anything starts."""

from __future__ import annotations

from pathlib import Path

import pytest
from builders import LOITER, SAR, campaign_file
from helpers.paths import REPO

from uav_campaigns.cli.campaign import _plan
from uav_campaigns.core.config import load_campaign
from uav_campaigns.core.plan import campaign_fingerprint
from uav_campaigns.errors import CampaignConfigError
from uav_common.errors import ConfigError
from uav_scenarios.core.config import Strategy, TimeMode

CAMPAIGNS = sorted((REPO / "config" / "campaigns").glob("*.yaml"))


@pytest.mark.parametrize("path", CAMPAIGNS, ids=[p.name for p in CAMPAIGNS])
def test_every_shipped_campaign_plans(path: Path) -> None:
    campaign = load_campaign(path)
    runs = _plan(campaign)
    assert len(runs) == len(campaign.arms) * len(campaign.seeds) * campaign.repeats
    assert len({r.key for r in runs}) == len(runs), "two runs of a shipped campaign share a configuration"
    assert campaign.name == path.stem


def test_the_shipped_campaigns_are_the_issue_s() -> None:
    names = {p.stem for p in CAMPAIGNS}
    assert {"smoke", "sar_strategies", "loiter_weights", "depth_sources"} <= names
    smoke = load_campaign(REPO / "config/campaigns/smoke.yaml")
    assert (len(smoke.arms), len(smoke.seeds), smoke.repeats) == (2, 2, 1)
    assert smoke.time_limit_s is not None
    assert smoke.time_limit_s <= 30
    sar = load_campaign(REPO / "config/campaigns/sar_strategies.yaml")
    assert len(sar.seeds) == 10
    strategies = {r.scenario.strategy for r in _plan(sar)}
    assert strategies == {Strategy.AUTONOMOUS, Strategy.LAWNMOWER, Strategy.EXPANDING_SQUARE}


def test_time_defaults_to_deterministic_lockstep(tmp_path: Path) -> None:
    path = campaign_file(tmp_path, "arms: {a: {}}\nseeds: [1]\n")
    campaign = load_campaign(path)
    assert campaign.time.mode is TimeMode.LOCKSTEP
    assert campaign.time.deterministic
    (run,) = _plan(campaign)
    assert run.scenario.time.mode is TimeMode.LOCKSTEP
    assert run.scenario.time.deterministic


@pytest.mark.parametrize(
    ("body", "says"),
    [
        ("arms: {a: {autonomy: {weightz: {age: 1}}}}\nseeds: [1]\n", "arm 'a'"),
        ("arms: {a: {autonomy.weightz.age: 1}}\nseeds: [1]\n", "'weightz'"),
        ("arms: {a: {autonomy: {weights: {speed: 1}}}}\nseeds: [1]\n", "unknown feature weight"),
        ("arms: {a: {stop: {time_limit: 5}}}\nseeds: [1]\n", "'time_limit'"),
        ("arms: {a: {}, b: {mision: loiter}}\nseeds: [1]\n", "arm 'b'"),
        ("arms: {a: {strategy: zigzag}}\nseeds: [1]\n", "'strategy'"),
        ("arms: {a: {name: other}}\nseeds: [1]\n", "may not override 'name'"),
        ("arms: {a: {}}\nseeds: [1]\noverrides: {wrld: {seed: 3}}\n", "'wrld'"),
    ],
)
def test_an_override_the_scenario_schema_lacks_is_an_error_naming_arm_and_key(
    tmp_path: Path, body: str, says: str
) -> None:
    campaign = load_campaign(campaign_file(tmp_path, body))
    with pytest.raises(CampaignConfigError) as err:
        _plan(campaign)
    assert says in str(err.value)
    assert str(campaign.source) in str(err.value)
    assert isinstance(err.value, ConfigError)  # exit code 2


@pytest.mark.parametrize(
    ("body", "says"),
    [
        ("arms: {a: {}, b: {}}\nseeds: []\n", "has no runs"),
        ("arms: {a: {}}\nseeds: [1, 2]\nrepeats: 0\n", "has no runs"),
        ("arms: {}\nseeds: [1]\n", "arms is empty"),
        ("arms: {a: {}}\n", "required key 'seeds'"),
        ("arms: {a: {}}\nseeds: [1, 1]\n", "distinct"),
        ("arms: {'a b': {}}\nseeds: [1]\n", "slugs"),
        ("arms: {a: {}}\nseeds: [1]\nsuccess: {x: 'coverage.mapped_pct about 3'}\n", "metric op number"),
        ("arms: {a: {}}\nseeds: [1]\nstatistics: {reference_arm: z}\n", "reference_arm"),
        ("arms: {a: {}}\nseeds: [1]\ntime: {mode: free, deterministic: true}\n", "deterministic"),
        ("arms: {a: {}}\nseeds: [1]\nrepeat: 2\n", "unknown key(s) 'repeat'"),
        ("arms: {a: {}}\nseeds: [1]\nseeds_apply_to: [wind]\n", "seeds_apply_to"),
    ],
)
def test_a_broken_campaign_file_names_the_file_and_key(tmp_path: Path, body: str, says: str) -> None:
    path = campaign_file(tmp_path, body)
    with pytest.raises(CampaignConfigError) as err:
        load_campaign(path)
    assert says in str(err.value)
    assert str(path) in str(err.value)


def test_a_missing_scenario_or_world_is_an_error(tmp_path: Path) -> None:
    missing = load_campaign(campaign_file(tmp_path, "arms: {a: {}}\nseeds: [1]\n", scenario=tmp_path / "nope.yaml"))
    with pytest.raises(ConfigError, match=r"nope\.yaml"):
        _plan(missing)
    no_world = load_campaign(campaign_file(tmp_path, "arms: {a: {world: {config: /nonexistent/w.yaml}}}\nseeds: [1]\n"))
    with pytest.raises(CampaignConfigError, match=r"w\.yaml"):
        _plan(no_world)


def test_the_fingerprint_ignores_layout_but_not_content(tmp_path: Path) -> None:
    for d in "abc":
        (tmp_path / d).mkdir()
    a = campaign_file(tmp_path / "a", "arms: {a: {}}\nseeds: [1, 2]\n")
    b = campaign_file(tmp_path / "b", "# a comment\narms:\n  a: {}\nseeds: [1, 2]   # two\n")
    c = campaign_file(tmp_path / "c", "arms: {a: {}}\nseeds: [1, 3]\n")
    fa, fb, fc = (campaign_fingerprint(load_campaign(p)) for p in (a, b, c))
    assert fa == fb
    assert fa != fc


def test_sar_seeds_move_the_person_not_the_world(tmp_path: Path) -> None:
    body = "arms: {a: {}}\nseeds: [3, 4]\nseeds_apply_to: [person]\n"
    runs = _plan(load_campaign(campaign_file(tmp_path, body, scenario=SAR)))
    assert [r.scenario.search.person.placement_seed for r in runs if r.scenario.search] == [3, 4]
    assert {r.scenario.world.seed for r in runs} == {None}
    assert LOITER.is_file()
