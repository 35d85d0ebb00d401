"""An interrupted run (SIGINT or SIGKILL) resumed from its checkpoint ends exactly where
the uninterrupted run ends, bit for bit, and its summary counts the whole run."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytestmark = [pytest.mark.slow]

# long enough that the run is still going when the test, on a loaded machine, sees the first
# checkpoint and signals (at 3 s a run once finished first and exited 0)
ARGS = ["simulate", "--example", "sphere-drop", "--resolution", "10", "--duration", "6.0", "--quiet", "--no-obj"]


def _env() -> dict:
    env = dict(os.environ)
    env.update({"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1", "TQDM_DISABLE": "1"})
    return env


def _run(out: Path, *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "tryon.cli", *ARGS, "--out", str(out), *extra], env=_env(),
                          capture_output=True, text=True, timeout=300)


def _interruptible() -> None:
    """In the child: SIGINT as a terminal delivers it, whatever this test process inherited
    or was left with by libraries (an ignored or blocked SIGINT passes on to a child, and
    the run then finishes and exits 0, as the suite once saw)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


def _interrupt(out: Path, sig: int) -> None:
    """Start a run and send `sig` as soon as its first checkpoint exists."""
    proc = subprocess.Popen([sys.executable, "-m", "tryon.cli", *ARGS, "--out", str(out)], env=_env(),
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, preexec_fn=_interruptible)
    checkpoint = out.with_name(out.name + ".partial") / "checkpoint.npz"
    deadline = time.monotonic() + 240
    while not checkpoint.exists():
        assert proc.poll() is None, f"the run ended before its first checkpoint: {proc.stderr.read()[-500:]}"
        assert time.monotonic() < deadline
        time.sleep(0.005)
    proc.send_signal(sig)
    rc = proc.wait(timeout=60)
    assert rc == (130 if sig == signal.SIGINT else -signal.SIGKILL), proc.stderr.read()[-500:]
    assert not out.exists() and checkpoint.exists()


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    out = tmp_path_factory.mktemp("full") / "run"
    done = _run(out)
    assert done.returncode == 0, done.stderr[-500:]
    return np.load(out / "frames.npz")["positions"], json.loads((out / "summary.json").read_text())


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGKILL], ids=["sigint", "sigkill"])
def test_resume_equals_uninterrupted(tmp_path, uninterrupted, sig):
    positions, summary = uninterrupted
    out = tmp_path / "run"
    _interrupt(out, sig)
    resumed = _run(out, "--resume")
    assert resumed.returncode == 0, resumed.stderr[-500:]
    again = np.load(out / "frames.npz")["positions"]
    s = json.loads((out / "summary.json").read_text())
    assert again.shape == positions.shape
    assert np.array_equal(again, positions), f"resumed run differs by {np.abs(again - positions).max():.3g} m"
    assert s["steps"] == summary["steps"] == 600 and s["resumed_at_step"] > 0
    assert s["substeps"] == summary["substeps"] and s["contacts_total"] == summary["contacts_total"]


def test_resume_of_a_changed_scene_is_refused(tmp_path):
    out = tmp_path / "run"
    _interrupt(out, signal.SIGKILL)
    changed = subprocess.run([sys.executable, "-m", "tryon.cli", *ARGS, "--dt", "0.005", "--out", str(out), "--resume"],
                             env=_env(), capture_output=True, text=True, timeout=120)
    assert changed.returncode == 2 and "different scene" in changed.stderr
