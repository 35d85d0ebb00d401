"""Output folders are owned: a run replaces only what tryon wrote (or an empty folder),
refuses anything else before any work, and never touches /, ~, . or its parents."""

import os
import time
from pathlib import Path

import pytest

from tryon.cli import main
from tryon.errors import OutputFolderError
from tryon.io.atomic import OWNER_MARKER, atomic_output_dir, check_output_dir, claim_work_dir, is_owned


def _users_folder(path: Path) -> Path:
    path.mkdir(parents=True)
    (path / "thesis.tex").write_text("years of work")
    return path


def test_a_foreign_folder_is_refused_and_left_alone(tmp_path):
    mine = _users_folder(tmp_path / "mine")
    with pytest.raises(OutputFolderError, match="not written by tryon.*--force"):
        check_output_dir(mine)
    with pytest.raises(OutputFolderError):
        with atomic_output_dir(mine) as tmp:
            (tmp / "x.txt").write_text("new")
    assert (mine / "thesis.tex").read_text() == "years of work"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine"]  # no temporary folder left behind


def test_owned_and_empty_folders_are_replaced(tmp_path):
    out = tmp_path / "out"
    out.mkdir()  # empty: fine
    with atomic_output_dir(out) as tmp:
        (tmp / "a.txt").write_text("1")
    assert is_owned(out) and (out / "a.txt").exists()
    with atomic_output_dir(out) as tmp:  # written by tryon: replaced
        (tmp / "b.txt").write_text("2")
    assert (out / "b.txt").exists() and not (out / "a.txt").exists() and (out / OWNER_MARKER).is_file()


def test_force_replaces_a_foreign_folder(tmp_path):
    mine = _users_folder(tmp_path / "mine")
    with atomic_output_dir(mine, force=True) as tmp:
        (tmp / "result.txt").write_text("ok")
    assert (mine / "result.txt").exists() and not (mine / "thesis.tex").exists()


@pytest.mark.parametrize("name", ["/", "~", ".", "..", "../.."])
def test_protected_folders_are_refused_even_with_force(tmp_path, monkeypatch, name):
    work = tmp_path / "a" / "b"
    work.mkdir(parents=True)
    monkeypatch.chdir(work)
    monkeypatch.setenv("HOME", str(tmp_path / "a"))
    target = os.path.expanduser(name)
    with pytest.raises(OutputFolderError, match="refusing"):
        check_output_dir(target, force=True)
    assert work.exists()


def test_a_file_or_an_unwritable_place_fails_before_the_run(tmp_path):
    (tmp_path / "f").write_text("x")
    with pytest.raises(OutputFolderError, match="is a file"):
        check_output_dir(tmp_path / "f")
    with pytest.raises(OutputFolderError, match="is a file"):
        check_output_dir(tmp_path / "f" / "sub")
    if os.geteuid() != 0:  # root may write anywhere
        ro = tmp_path / "ro"
        ro.mkdir(mode=0o500)
        with pytest.raises(OutputFolderError, match="no permission"):
            check_output_dir(ro / "out")


def test_work_folders_are_claimed_like_outputs(tmp_path):
    partial = _users_folder(tmp_path / "run.partial")
    with pytest.raises(OutputFolderError):
        claim_work_dir(partial)
    work = claim_work_dir(tmp_path / "other.partial")
    (work / "checkpoint.npz").write_bytes(b"1")
    assert (claim_work_dir(work, resume=True) / "checkpoint.npz").exists()  # resume keeps it
    assert not (claim_work_dir(work) / "checkpoint.npz").exists()  # a fresh run clears its own folder


COMMANDS = {
    "simulate": ["simulate", "--example", "hanging", "--resolution", "6", "--duration", "0.05", "--quiet"],
    "drape": ["drape", "--height-cm", "172", "--weight-kg", "70", "--gender", "male", "--quiet"],
    "fit-fabric": ["fit-fabric", "missing.npz", "--quiet"],
    "control": ["control", "--example", "basket", "--iterations", "1", "--quiet"],
}


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_every_command_refuses_a_foreign_out_at_once(tmp_path, capsys, command):
    mine = _users_folder(tmp_path / "mine")
    t0 = time.perf_counter()
    rc = main([*COMMANDS[command], "--out", str(mine)])
    err = capsys.readouterr().err
    assert rc == 2 and "not written by tryon" in err and err.count("\n") == 1
    assert time.perf_counter() - t0 < 10.0  # before the body fit, the simulation or the fit
    assert sorted(p.name for p in mine.iterdir()) == ["thesis.tex"]


def test_animate_refuses_a_foreign_out(tmp_path, capsys):
    mine = _users_folder(tmp_path / "mine")
    rc = main(["animate", str(tmp_path / "no-drape"), "--out", str(mine), "--quiet"])
    assert rc == 2 and "not written by tryon" in capsys.readouterr().err
    assert (mine / "thesis.tex").exists()


def test_simulate_out_dotdot_is_refused(tmp_path, monkeypatch, capsys):
    work = tmp_path / "w"
    work.mkdir()
    (tmp_path / "keep.txt").write_text("x")
    monkeypatch.chdir(work)
    rc = main(["simulate", "--example", "hanging", "--resolution", "6", "--duration", "0.05", "--quiet",
               "--out", "..", "--force"])
    assert rc == 2 and "refusing" in capsys.readouterr().err
    assert (tmp_path / "keep.txt").exists() and work.exists()


def test_simulate_replaces_its_own_output(tmp_path):
    out = tmp_path / "run"
    args = ["simulate", "--example", "hanging", "--resolution", "6", "--duration", "0.05", "--quiet", "--no-obj",
            "--out", str(out)]
    assert main(args) == 0 and is_owned(out)
    assert main(args) == 0 and (out / "summary.json").exists()
    assert not (tmp_path / "run.partial").exists()


def test_a_folder_holding_the_home_folder_is_refused_even_with_force(tmp_path, monkeypatch):
    home = tmp_path / "users" / "alice"
    home.mkdir(parents=True)
    (home / "thesis.tex").write_text("years of work")
    monkeypatch.setenv("HOME", str(home))
    with pytest.raises(OutputFolderError, match="contains your home folder"):
        check_output_dir(tmp_path / "users", force=True)
    assert (home / "thesis.tex").exists()


def test_dot_dot_is_folded_before_the_check(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _users_folder(tmp_path / "x")
    with pytest.raises(OutputFolderError, match="not written by tryon"):
        check_output_dir("nope/../x")  # what the run would write is x: refused before any work
    assert not (tmp_path / "nope").exists()
    assert check_output_dir("a/b/../c") == Path("a/c")


def test_two_runs_never_share_a_working_folder(tmp_path):
    work = claim_work_dir(tmp_path / "run.partial")
    script = f"from tryon.io.atomic import claim_work_dir; claim_work_dir({str(work)!r})"
    import subprocess
    import sys

    other = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert other.returncode != 0 and "another tryon run is writing" in other.stderr
    assert work.exists()


def test_a_linked_marker_does_not_make_a_folder_owned(tmp_path):
    mine = _users_folder(tmp_path / "mine")
    (tmp_path / "fake.json").write_text('{"written_by": "tryon"}')
    (mine / OWNER_MARKER).symlink_to(tmp_path / "fake.json")
    assert not is_owned(mine)
    with pytest.raises(OutputFolderError):
        check_output_dir(mine)
