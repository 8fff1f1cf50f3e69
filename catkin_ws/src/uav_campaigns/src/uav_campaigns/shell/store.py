"""The campaign directory on disk: its identity, its manifest and its run folders.

::

    DIR/campaign.json      which campaign file made it (fingerprint, text, parsed settings) and its plan
    DIR/manifest.jsonl     append-only events (uav_campaigns.core.manifest), flushed and fsynced one by one
    DIR/runs/<arm>/s<seed>-r<repeat>-t<try>/   one folder per try of a run, as uav-run writes it
    DIR/runs.csv, summary.csv, paired.csv, success.csv, report.html, figures/

A directory made by a different campaign file is refused (:class:`CampaignDirError`), so results
of two campaigns are never mixed. A crash while a manifest line was being written leaves at worst
one truncated last line, which reading skips.
"""

from __future__ import annotations

import json
import os
import threading
import time
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from uav_campaigns.core.config import Campaign
from uav_campaigns.core.plan import PlannedRun
from uav_campaigns.errors import CampaignDirError
from uav_common.config import ConfigError, from_mapping, to_mapping

__all__ = ["CampaignDir", "PlanEntry"]

PlanEntry = dict[str, Any]


class CampaignDir:
    """One campaign directory (module docstring)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.identity_path = path / "campaign.json"
        self.manifest_path = path / "manifest.jsonl"
        self._lock = threading.Lock()

    # ------------------------------------------------------------------------------------------- identity

    def identity(self) -> dict[str, Any] | None:
        try:
            data = json.loads(self.identity_path.read_text())
        except FileNotFoundError:
            return None
        except (OSError, json.JSONDecodeError) as err:
            msg = f"{self.identity_path}: unreadable ({err}); this is not a campaign directory uav-campaign can use"
            raise CampaignDirError(msg) from err
        if not isinstance(data, dict) or "campaign_id" not in data:
            msg = f"{self.identity_path} is not a campaign identity file; use another --out directory"
            raise CampaignDirError(msg)
        return data

    def check(self, campaign: Campaign, fingerprint: str) -> dict[str, Any] | None:
        """Refuse a directory made by another campaign file, or a non-empty folder that is no campaign's.

        Returns:
            the existing identity (None for a new or empty directory).
        """
        ident = self.identity()
        if ident is None:
            if self.path.exists() and any(self.path.iterdir()):
                msg = (
                    f"{self.path} exists, is not empty and is not a campaign directory (no campaign.json); "
                    "give --out a new or empty directory"
                )
                raise CampaignDirError(msg)
            return None
        if ident["campaign_id"] != fingerprint:
            msg = (
                f"{self.path} was made by campaign file {ident.get('campaign_file')} "
                f"(fingerprint {ident['campaign_id']}), "
                f"not by {campaign.source} (fingerprint {fingerprint}): results of two campaigns are never mixed. "
                "Give --out another directory (or delete this one to start over)."
            )
            raise CampaignDirError(msg)
        return ident

    def write_identity(
        self, campaign: Campaign, fingerprint: str, campaign_text: str, plan: Iterable[PlannedRun]
    ) -> None:
        """campaign.json: what made this directory and the current plan (rewritten atomically)."""
        self.path.mkdir(parents=True, exist_ok=True)
        data = {
            "campaign_id": fingerprint,
            "campaign_file": str(campaign.source),
            "campaign_text": campaign_text,
            "campaign": to_mapping(campaign),
            "plan": [
                {"key": r.key, "arm": r.arm, "seed": r.seed, "repeat": r.repeat, "config_hash": r.config_hash}
                for r in plan
            ],
        }
        tmp = self.identity_path.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(data, indent=1) + "\n")
        os.replace(tmp, self.identity_path)

    def load(self) -> tuple[Campaign, list[PlanEntry]]:
        """The campaign and plan recorded in campaign.json (for ``uav-campaign report``).

        Raises:
            CampaignDirError: no campaign.json, or one this version cannot read.
        """
        ident = self.identity()
        if ident is None:
            msg = f"{self.path} is not a campaign directory (no campaign.json); run `uav-campaign run` first"
            raise CampaignDirError(msg)
        try:
            campaign = from_mapping(Campaign, ident["campaign"], source=str(self.identity_path), prefix="campaign")
        except (ConfigError, KeyError) as err:
            msg = f"{self.identity_path}: cannot read the campaign it records: {err}"
            raise CampaignDirError(msg) from err
        return campaign, list(ident.get("plan") or [])

    # ------------------------------------------------------------------------------------------- manifest

    def append(self, event: Mapping[str, Any]) -> None:
        """Append one event (stamped ``t``, Unix seconds, unless it has one) and make it durable before returning."""
        line = json.dumps({"t": time.time(), **dict(event)}, default=str, allow_nan=True) + "\n"
        with self._lock:
            self.path.mkdir(parents=True, exist_ok=True)
            with self.manifest_path.open("a", encoding="utf-8") as fh:
                fh.write(line)
                fh.flush()
                os.fsync(fh.fileno())

    def events(self) -> list[dict[str, Any]]:
        """Every complete event of the manifest, in order (a truncated last line is skipped)."""
        try:
            text = self.manifest_path.read_text(encoding="utf-8")
        except FileNotFoundError:
            return []
        out: list[dict[str, Any]] = []
        for line in text.splitlines():
            if not line.strip():
                continue
            try:
                ev = json.loads(line)
            except json.JSONDecodeError:
                continue
            if isinstance(ev, dict):
                out.append(ev)
        return out

    # ------------------------------------------------------------------------------------------- run folders

    def run_dir(self, run: PlannedRun, try_no: int) -> Path:
        return self.path / "runs" / run.arm / f"{run.slug}-t{try_no}"
