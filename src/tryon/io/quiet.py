"""Start third-party runtimes without talking about hardware the user does not have.

Anny skins bodies with NVIDIA warp. On its first use warp prints a greeting to stdout and,
on a machine without an NVIDIA driver, "Warp CUDA warning: Could not find or load the
NVIDIA CUDA driver" from C code straight to file descriptor 2. Neither tells a user of a
CPU-only try-on anything, so warp is started here with its log level at warnings and, when
no driver can be loaded, with descriptor 2 pointed at /dev/null for the moment it starts.
Where a driver exists warp starts as it would, and any real error still raises.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import sys
import threading
from collections.abc import Iterator

_lock = threading.Lock()


def cuda_driver_present() -> bool:
    """Whether the NVIDIA driver library can be loaded (what warp looks for)."""
    for name in ("libcuda.so", "libcuda.so.1"):
        try:
            ctypes.CDLL(name)
            return True
        except OSError:
            continue
    return False


@contextlib.contextmanager
def stderr_descriptor_silenced() -> Iterator[None]:
    """File descriptor 2 points at /dev/null inside the block (C code's fprintf included).
    The descriptor is the process's: what other threads write to it meanwhile is lost too,
    so keep the block to the one call that needs it."""
    if sys.stderr is not None:  # None under pythonw and some detached services
        sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def init_warp_quietly() -> None:
    """Start warp once, without its greeting or its missing-driver warning."""
    import warp
    from warp._src import context

    with _lock:
        if context.runtime is not None:
            return
        warp.config.log_level = max(warp.config.log_level, warp.LOG_WARNING)
        if cuda_driver_present():
            warp.init()
            return
        with stderr_descriptor_silenced():
            warp.init()
