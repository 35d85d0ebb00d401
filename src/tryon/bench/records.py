"""What the benchmarks that write a list of records share: the host stamped on every
record, the JSON written atomically, and torch on one thread for the run."""

from __future__ import annotations

import platform

import torch

from tryon.io.atomic import atomic_write
from tryon.io.json_safe import dumps_json
from tryon.io.threads import one_torch_thread  # noqa: F401  (the benches' import of it)


def write_records(json_path: str, records: list[dict], **extra) -> None:
    """Stamp every record with the host (machine, Python, torch) and `extra`, then write
    the list as JSON (atomic)."""
    host = {"machine": platform.machine(), "python": platform.python_version(), "torch": torch.__version__, **extra}
    for r in records:
        r.update(host)
    with atomic_write(json_path) as fh:
        fh.write(dumps_json(records, indent=2))
