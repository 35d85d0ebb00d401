"""What the benchmarks that write a list of records share: the host stamped on every
record, the JSON written atomically, and torch on one thread for the run."""

from __future__ import annotations

import platform
from collections.abc import Iterator
from contextlib import contextmanager

import torch

from tryon.io.atomic import atomic_write
from tryon.io.json_safe import dumps_json


def write_records(json_path: str, records: list[dict], **extra) -> None:
    """Stamp every record with the host (machine, Python, torch) and `extra`, then write
    the list as JSON (atomic)."""
    host = {"machine": platform.machine(), "python": platform.python_version(), "torch": torch.__version__, **extra}
    for r in records:
        r.update(host)
    with atomic_write(json_path) as fh:
        fh.write(dumps_json(records, indent=2))


@contextmanager
def one_torch_thread() -> Iterator[None]:
    """torch on one thread inside the block (many small tensor operations: a thread pool
    only adds contention), its previous thread count restored after."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)
