"""Shared CLI pieces: common options, JSON printing, progress bars."""

from __future__ import annotations

import argparse
import json
import sys
from contextlib import contextmanager

from tqdm import tqdm


def add_seed_device(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument("--device", default="cpu", help="torch device: cpu or cuda (default cpu)")


def add_overwrite(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--overwrite", action="store_true", help="replace existing outputs")


def print_json(obj) -> None:
    json.dump(obj, sys.stdout, indent=2)
    sys.stdout.write("\n")


@contextmanager
def progress_bar(total: int | None = None, desc: str = "", unit: str = "it"):
    """A tqdm bar on stderr; yields a callback ``update(n=1, **postfix)`` for the API."""
    bar = tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, dynamic_ncols=True, leave=False)

    def update(n: int = 1, **postfix):
        if postfix:
            bar.set_postfix(postfix, refresh=False)
        bar.update(n)

    try:
        yield update
    finally:
        bar.close()
