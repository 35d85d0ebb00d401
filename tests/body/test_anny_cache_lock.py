"""The Anny cache's build lock: processes that start together wait for one build, a
held lock ends the wait with an error that names it, a read-only cache is just read."""

import fcntl

import pytest

from tryon.body.anny_model import cache_lock
from tryon.errors import TryonError


def test_a_held_lock_ends_the_wait_with_an_error_naming_the_lock(tmp_path):
    with open(tmp_path / ".tryon-build.lock", "a") as other:  # another open file: another holder
        fcntl.flock(other, fcntl.LOCK_EX)
        with pytest.raises(TryonError, match=r"\.tryon-build\.lock.*over 0 s"):
            with cache_lock(tmp_path, wait_s=0.3):
                pass
    with cache_lock(tmp_path, wait_s=0.3):  # released: taken at once
        pass


def test_a_read_only_cache_needs_no_lock(tmp_path, monkeypatch):
    def read_only(path, *args, **kwargs):
        raise PermissionError(13, "Permission denied", str(path))

    monkeypatch.setattr("tryon.body.anny_model.open", read_only, raising=False)
    entered = False
    with cache_lock(tmp_path):
        entered = True
    assert entered and not (tmp_path / ".tryon-build.lock").exists()
