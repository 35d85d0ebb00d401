"""What the benchmarks share: the host stamped on every record, the JSON written
atomically, torch on one thread for the run, and progress lines for long runs."""

from __future__ import annotations

import platform
import sys
import time

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


def progress_line(bench: str, message: str, started: float | None = None) -> None:
    """One line on stderr saying where a long bench is (`[bench learned 3.2 min] ...`):
    a bench run from a script or CI shows no progress bar, and a silent minute looks hung."""
    when = f" {(time.perf_counter() - started) / 60:.1f} min" if started is not None else ""
    print(f"[bench {bench}{when}] {message}", file=sys.stderr, flush=True)
