"""A campaign -> its runs: one effective scenario per (arm, seed, repeat), validated, hashed and keyed.

Pure: the base scenario comes in as the mapping read from its file, and the world files' text
through ``read_world`` (the shell passes a file reader). Each run's effective scenario is the base
with the campaign's shared ``overrides`` and then the arm's merged over it
(:func:`uav_common.config.deep_merge`), the seed applied
(``Campaign.seeds_apply_to``), and the campaign's time limit, time mode and recording; it is parsed
with the scenario schema itself (:class:`uav_scenarios.core.config.Scenario`), so an override key the
schema does not have is an error naming the campaign file, the arm and the key before anything starts.

A run's **configuration hash** is the SHA-256 of its effective scenario in canonical JSON, with the
run's name, description, wall-clock guard and file paths left out and the world file's *content* hash in place of its
path: the same configuration gives the same hash on any machine and in any campaign. The run's
**key** is the hash and the repeat index: a re-run of the campaign skips every key already finished.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from uav_campaigns.core.config import Campaign
from uav_campaigns.errors import CampaignConfigError
from uav_common.config import ConfigError, deep_merge, from_mapping, set_dotted, to_mapping
from uav_scenarios.core.config import Scenario

__all__ = ["PlannedRun", "arm_overrides", "campaign_fingerprint", "canonical_json", "plan_runs", "sha256_text"]


@dataclass(frozen=True)
class PlannedRun:
    """One (arm, seed, repeat) of a campaign."""

    arm: str
    seed: int
    repeat: int
    #: SHA-256 (hex) of the effective configuration (module docstring).
    config_hash: str
    #: The effective scenario (``source`` is the base scenario file, so relative paths resolve as there).
    scenario: Scenario

    @property
    def key(self) -> str:
        """What the manifest keys the run by: its configuration and its repeat index."""
        return f"{self.config_hash[:20]}-r{self.repeat}"

    @property
    def label(self) -> str:
        """``arm/s<seed>/r<repeat>``, for people."""
        return f"{self.arm}/s{self.seed}/r{self.repeat}"

    @property
    def slug(self) -> str:
        """A folder name: ``s<seed>-r<repeat>``."""
        return f"s{self.seed}-r{self.repeat}"


def sha256_text(text: str) -> str:
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def canonical_json(data: Any) -> str:
    """Sorted keys, no whitespace, floats as Python writes them: equal data, equal text."""
    return json.dumps(data, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False)


def arm_overrides(overrides: Mapping[str, Any] | None) -> dict[str, Any]:
    """An arm's overrides as one nested mapping (``a.b.c: v`` keys expanded, nested mappings kept)."""
    out: dict[str, Any] = {}
    for key, value in (overrides or {}).items():
        if "." in str(key):
            nested: dict[str, Any] = {}
            set_dotted(nested, str(key), value)
            out = deep_merge(out, nested)
        else:
            out = deep_merge(out, {str(key): value})
    return out


def _apply_seed(data: dict[str, Any], seed: int, targets: tuple[str, ...]) -> dict[str, Any]:
    patch: dict[str, Any] = {}
    if "world" in targets:
        patch["world"] = {"seed": seed}
    if "person" in targets and isinstance(data.get("search"), Mapping):
        patch["search"] = {"person": {"placement_seed": seed}}
    if "noise" in targets:
        patch["node_params"] = {"sim_bridge": {"noise": {"seed": seed}}, "sitl": {"estimator": {"seed": seed}}}
    return deep_merge(data, patch)


def _effective(campaign: Campaign, base: Mapping[str, Any], arm: str, seed: int) -> Scenario:
    where = f"{campaign.source}: arm '{arm}'"
    try:
        overrides = deep_merge(arm_overrides(campaign.overrides), arm_overrides(campaign.arms[arm]))
    except ConfigError as err:
        msg = f"{where}: {err}"
        raise CampaignConfigError(msg) from err
    if "source" in overrides or "name" in overrides:
        msg = f"{where}: an arm may not override 'name' or 'source' (the campaign names every run)"
        raise CampaignConfigError(msg)
    data = _apply_seed(deep_merge(base, overrides), seed, campaign.seeds_apply_to)
    data["name"] = f"{campaign.name}-{arm}-s{seed}"
    try:
        scenario = from_mapping(Scenario, data, source=f"{where} (scenario {campaign.scenario.name} + overrides)")
    except ConfigError as err:
        msg = f"{err}; an arm's overrides take the scenario file's keys (docs/scenarios.md)"
        raise CampaignConfigError(msg) from err
    try:
        stop = scenario.stop
        if campaign.time_limit_s is not None:
            stop = replace(stop, time_limit_s=campaign.time_limit_s)
        # the mission manager's own wall-clock guard never outlasts the campaign's budget for the run
        stop = replace(stop, wall_timeout_s=min(stop.wall_timeout_s, campaign.budget_s(stop.time_limit_s)))
        recording = (
            replace(scenario.recording, enabled=False)
            if campaign.record == "none"
            else replace(scenario.recording, enabled=True, preset=campaign.record)
        )
        return replace(
            scenario, stop=stop, time=campaign.time.time_spec(), recording=recording, source=campaign.scenario
        )
    except ValueError as err:
        msg = f"{where}: the campaign's settings do not fit this scenario: {err}"
        raise CampaignConfigError(msg) from err


def config_hash(scenario: Scenario, world_text: str) -> str:
    """The configuration hash of an effective scenario (module docstring)."""
    data = to_mapping(scenario)
    for key in ("name", "description", "source"):
        data.pop(key, None)
    data["stop"].pop("wall_timeout_s", None)  # a guard against hangs, not part of what the run does
    data["world"]["config"] = f"sha256:{sha256_text(world_text)}"
    return sha256_text(canonical_json(data))


def world_path(scenario: Scenario) -> Path:
    """The scenario's world file, resolved against the base scenario file's folder."""
    return scenario.world_config_path


def plan_runs(
    campaign: Campaign,
    base: Mapping[str, Any],
    read_world: Callable[[Path], str],
) -> list[PlannedRun]:
    """Every run of the campaign, arm by arm, seed by seed, repeat by repeat.

    Args:
        campaign: the parsed campaign (:func:`uav_campaigns.core.config.load_campaign`).
        base: the base scenario file's top-level mapping, as read.
        read_world: returns a world config file's text (raises ``ConfigError`` if it cannot).

    Raises:
        CampaignConfigError: an arm's overrides are not valid scenario keys or values, or a world file is missing;
            the message names the campaign file, the arm and the key.
    """
    runs: list[PlannedRun] = []
    worlds: dict[Path, str] = {}
    for arm in campaign.arms:
        for seed in campaign.seeds:
            scenario = _effective(campaign, base, arm, seed)
            path = world_path(scenario)
            if path not in worlds:
                try:
                    worlds[path] = read_world(path)
                except ConfigError as err:
                    msg = f"{campaign.source}: arm '{arm}': world.config: {err}"
                    raise CampaignConfigError(msg) from err
            digest = config_hash(scenario, worlds[path])
            runs.extend(PlannedRun(arm, seed, r, digest, scenario) for r in range(campaign.repeats))
    return runs


def campaign_fingerprint(campaign: Campaign) -> str:
    """What identifies a campaign file: its parsed content (not its comments or layout), 16 hex digits.

    A campaign directory belongs to one fingerprint; a different campaign file is refused there.
    """
    data = to_mapping(campaign)
    data.pop("source", None)
    data["scenario"] = Path(str(data["scenario"])).name
    return sha256_text(canonical_json(data))[:16]
