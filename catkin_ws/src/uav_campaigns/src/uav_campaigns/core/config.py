"""Campaign files (``config/campaigns/*.yaml``) as frozen dataclasses.

A campaign names a base scenario, its *arms* (each a set of scenario overrides), the seeds, the
repeats, the simulated time limit and the time mode. Every (arm, seed, repeat) is one run of
``uav-run``. The file is parsed once, strictly (:func:`uav_common.config.load_config`): an unknown
key or a wrong type fails with the file and the key. Arm overrides are checked against the
scenario schema later, by :func:`uav_campaigns.core.plan.plan_runs`, before anything starts.

Example::

    scenario: ../scenarios/search_and_rescue.yaml
    arms:
      mcdm: {}
      lawnmower: {strategy: lawnmower}
    seeds: [1, 2, 3]
    repeats: 1
    time_limit_s: 300
    time: {mode: lockstep, deterministic: true}
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

from uav_campaigns.errors import CampaignConfigError
from uav_common.config import config_errors_as, load_config
from uav_scenarios.core.config import TimeMode, TimeSpec

__all__ = [
    "DEFAULT_KEY_METRICS",
    "Campaign",
    "CampaignTime",
    "StatisticsSpec",
    "load_campaign",
]

#: What each seed is applied to: the world generator's seed, the person's placement seed (search and
#: rescue) and the noise seeds (the sensor bridge's depth/pose noise, the SITL's estimator noise).
SeedTarget = Literal["world", "person", "noise"]
SEED_TARGETS: tuple[SeedTarget, ...] = ("world", "person", "noise")

#: The metrics the report plots and the campaign summary prints, in order (metrics.json's dotted names;
#: ``freshness.*`` are derived from the run's time series, docs/campaigns.md).
DEFAULT_KEY_METRICS = (
    "time.complete_s",
    "coverage.mapped_pct",
    "map_accuracy.iou",
    "map_accuracy.iou_observed",
    "battery.used_pct",
    "collisions.count",
    "detection.precision",
    "detection.recall",
    "freshness.mean_cell_age_s",
)

_SLUG = re.compile(r"^[A-Za-z0-9_-]+$")
_SUCCESS = re.compile(r"^\s*([A-Za-z0-9_.]+)\s*(>=|<=|==|!=|>|<)\s*(\S+)\s*$")


@dataclass(frozen=True)
class CampaignTime:
    """How simulated time runs in every run of the campaign (the scenario's ``time`` is replaced).

    The default is lockstep and deterministic: the same run twice gives the same metrics, so the
    spread between runs comes from the seeds, not from the machine's load.
    """

    mode: TimeMode = TimeMode.LOCKSTEP
    deterministic: bool = True
    step_s: float = 0.1
    speed_factor: float = 1.0

    def __post_init__(self) -> None:
        if self.deterministic and self.mode is not TimeMode.LOCKSTEP:
            msg = "deterministic: true needs mode: lockstep"
            raise ValueError(msg)
        if self.step_s <= 0 or self.speed_factor <= 0:
            msg = "step_s and speed_factor must be > 0"
            raise ValueError(msg)

    def time_spec(self) -> TimeSpec:
        return TimeSpec(
            mode=self.mode, speed_factor=self.speed_factor, step_s=self.step_s, deterministic=self.deterministic
        )


@dataclass(frozen=True)
class StatisticsSpec:
    """Settings of the campaign's statistics (docs/campaigns.md)."""

    #: Confidence level of every interval (bootstrap, paired difference, Wilson).
    confidence: float = 0.95
    #: Bootstrap resamples per interval.
    resamples: int = 10000
    #: Seed of the bootstrap's generator: the same runs give the same intervals.
    seed: int = 0
    #: Paired comparisons are every other arm against this one (default: the first arm).
    reference_arm: str | None = None

    def __post_init__(self) -> None:
        if not 0.5 <= self.confidence < 1.0:
            msg = f"confidence must be within [0.5, 1), got {self.confidence}"
            raise ValueError(msg)
        if self.resamples < 100:
            msg = f"resamples must be >= 100, got {self.resamples}"
            raise ValueError(msg)


@dataclass(frozen=True)
class Campaign:
    #: The base scenario file (relative paths are relative to the campaign file).
    scenario: Path
    #: Arm name -> scenario overrides (nested mappings merge key by key; ``a.b.c: v`` keys are dotted paths).
    arms: dict[str, dict[str, Any] | None]
    #: One run per seed (and repeat) and arm; see ``seeds_apply_to``.
    seeds: tuple[int, ...]
    name: str = ""
    description: str = ""
    #: Scenario overrides every arm shares, merged before the arm's own (same form as an arm's).
    overrides: dict[str, Any] = field(default_factory=dict)
    seeds_apply_to: tuple[SeedTarget, ...] = SEED_TARGETS
    repeats: int = 1
    #: Simulated seconds per run (``stop.time_limit_s``); null keeps each arm's scenario value.
    time_limit_s: float | None = None
    time: CampaignTime = field(default_factory=CampaignTime)
    #: What each run records: ``report`` (what its report needs), ``replay``, or ``none`` (no per-run report).
    record: Literal["report", "replay", "none"] = "report"
    #: A run that crashes, hangs or times out is tried again up to this many times in all (across invocations).
    max_attempts: int = 3
    #: Wall-clock budget of one run, seconds; past it the run is stopped and recorded as hung.
    #: Null: 240 s + 20 wall seconds per simulated second (deterministic lockstep runs at ~0.3x).
    run_budget_s: float | None = None
    #: CPU cores one run keeps busy; the embedded cluster runs ``cores // cores_per_run`` runs at once.
    cores_per_run: float = 2.0
    #: The metrics the report plots and the summary prints first.
    key_metrics: tuple[str, ...] = DEFAULT_KEY_METRICS
    #: Success criteria reported as rates with Wilson intervals: name -> ``"metric op number"``
    #: (op one of ``>= > <= < == !=``), e.g. ``found: "time.complete_s >= 0"``.
    success: dict[str, str] = field(default_factory=dict)
    statistics: StatisticsSpec = field(default_factory=StatisticsSpec)
    #: The file this campaign came from (set by :func:`load_campaign`).
    source: Path | None = None

    def __post_init__(self) -> None:
        if not self.arms:
            msg = "arms is empty: name at least one arm (an arm with no overrides is `name: {}`)"
            raise ValueError(msg)
        bad = [a for a in self.arms if not _SLUG.match(a)]
        if bad or (self.name and not _SLUG.match(self.name)):
            msg = f"the name and the arm names must be slugs (letters, digits, - and _): {bad or self.name!r}"
            raise ValueError(msg)
        if not self.seeds or self.repeats < 1:
            msg = (
                f"every arm ({', '.join(self.arms)}) has no runs: seeds is {list(self.seeds)} and repeats "
                f"{self.repeats}; give at least one seed and repeats >= 1"
            )
            raise ValueError(msg)
        if len(set(self.seeds)) != len(self.seeds) or any(s < 0 for s in self.seeds):
            msg = f"seeds must be distinct and >= 0, got {list(self.seeds)} (repeats runs a seed more than once)"
            raise ValueError(msg)
        if len(set(self.seeds_apply_to)) != len(self.seeds_apply_to):
            msg = f"seeds_apply_to has duplicates: {list(self.seeds_apply_to)}"
            raise ValueError(msg)
        self._check_limits()
        for name, rule in self.success.items():
            if not _SLUG.match(name):
                msg = f"success criterion names must be slugs, got {name!r}"
                raise ValueError(msg)
            parse_success(rule)
        ref = self.statistics.reference_arm
        if ref is not None and ref not in self.arms:
            msg = f"statistics.reference_arm {ref!r} is not an arm; arms: {', '.join(self.arms)}"
            raise ValueError(msg)

    def _check_limits(self) -> None:
        limits = {
            "time_limit_s": self.time_limit_s,
            "run_budget_s": self.run_budget_s,
            "cores_per_run": self.cores_per_run,
            "max_attempts": self.max_attempts,
        }
        for name, value in limits.items():
            if value is not None and not (math.isfinite(value) and value > 0):
                msg = f"{name} must be > 0, got {value}"
                raise ValueError(msg)

    @property
    def arm_names(self) -> tuple[str, ...]:
        return tuple(self.arms)

    @property
    def reference_arm(self) -> str:
        return self.statistics.reference_arm or next(iter(self.arms))

    @property
    def runs_per_arm(self) -> int:
        return len(self.seeds) * self.repeats

    def budget_s(self, time_limit_s: float) -> float:
        """The wall-clock budget of a run of ``time_limit_s`` simulated seconds."""
        if self.run_budget_s is not None:
            return self.run_budget_s
        return 240.0 + 20.0 * time_limit_s


def parse_success(rule: str) -> tuple[str, str, float]:
    """``"coverage.mapped_pct >= 10"`` -> ``("coverage.mapped_pct", ">=", 10.0)``.

    Raises:
        ValueError: the rule is not ``metric op number``.
    """
    m = _SUCCESS.match(rule)
    if m is None:
        msg = f"success rule {rule!r} must read 'metric op number', op one of >= > <= < == !="
        raise ValueError(msg)
    try:
        value = float(m.group(3))
    except ValueError as err:
        msg = f"success rule {rule!r}: {m.group(3)!r} is not a number"
        raise ValueError(msg) from err
    return m.group(1), m.group(2), value


def load_campaign(path: Path) -> Campaign:
    """Parse and validate a campaign file (not yet its arms against the scenario schema).

    Raises:
        CampaignConfigError: the file is missing, not YAML, has an unknown key, a wrong type or an
            inconsistent setting; the message names the file and the key.
    """
    with config_errors_as(CampaignConfigError):
        campaign = load_config(Campaign, path)
    if campaign.source is not None:
        msg = f"{path}: 'source' is set by the loader, remove it from the file"
        raise CampaignConfigError(msg)
    scenario = (path.resolve().parent / campaign.scenario).resolve()  # an absolute scenario path stays as it is
    return replace(campaign, source=path.resolve(), scenario=scenario, name=campaign.name or path.stem)
