"""Batch work on one machine or a Ray cluster: ``facetex batch transfer|persona|puppet``.

- :func:`run_batch` runs a list of :class:`Item` on an engine, resumably, with claims that hold
  across processes and hosts sharing the output folder (a local or NFS folder, or an fsspec URL
  such as ``s3://bucket/aug``) and an append-only ``manifest.jsonl``;
- :func:`batch_status` reads a batch folder: counts per state, throughput, failures, slowest items;
- :func:`map_items` maps a function over an engine (the benches);
- engines (:mod:`facetex.batch.engines`): :class:`LocalEngine` (worker processes with their own
  thread budgets), :class:`RayEngine` (a Ray cluster, or a local Ray), :class:`InlineEngine`;
- items of the three workloads: :func:`transfer_items`, :func:`persona_items`, :func:`puppet_items`.
"""

from ._items import (folder_settings, pairs_from_folders, persona_items, puppet_items, read_pairs_csv, run_persona_item,
                     run_puppet_item, run_transfer_item, transfer_items)
from ._run import BatchSummary, Item, map_items, run_batch, run_tag
from ._status import batch_status
from .engines import (Engine, EngineError, InlineEngine, LocalEngine, Outcome, RayEngine, Resources,
                      make_engine)

__all__ = ["run_batch", "map_items", "Item", "BatchSummary", "Engine", "EngineError", "InlineEngine",
           "LocalEngine", "RayEngine", "Outcome", "Resources", "make_engine", "transfer_items", "persona_items",
           "puppet_items", "read_pairs_csv", "pairs_from_folders", "run_transfer_item", "run_persona_item",
           "run_puppet_item", "run_tag", "folder_settings", "batch_status"]
