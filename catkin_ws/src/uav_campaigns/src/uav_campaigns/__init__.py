"""Campaigns: many isolated scenario runs on Dask, a manifest, and the statistics over them (docs/campaigns.md)."""
