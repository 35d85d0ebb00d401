"""Pictures of the web viewer taken in headless Chromium (Debian's `chromium` package):
what a user would see in the browser, for reports and for the viewer's own test."""

from __future__ import annotations

import re
import shutil
import subprocess
import tempfile
from pathlib import Path

from tryon.errors import TryonError
from tryon.viewer.export import LiveSource, start_server

BROWSERS = ("chromium", "chromium-browser", "google-chrome")
# Software WebGL (SwiftShader) and no network chatter: the page only talks to 127.0.0.1.
CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync", "--no-first-run",
                  "--disable-quic", "--hide-scrollbars")


def find_browser() -> str:
    for name in BROWSERS:
        path = shutil.which(name)
        if path:
            return path
    raise TryonError("no Chromium found for viewer screenshots; install Debian's `chromium` package "
                     "(scripts/system-deps.sh does it)")


def _chromium(browser: str, profile: str, size: tuple[int, int], extra: list[str], timeout: float) -> subprocess.CompletedProcess:
    cmd = [browser, *CHROMIUM_FLAGS, f"--user-data-dir={profile}", f"--window-size={size[0]},{size[1]}",
           "--virtual-time-budget=20000", *extra]
    try:
        return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired as exc:
        raise TryonError(f"headless Chromium did not finish within {timeout:.0f} s") from exc


def screenshot_viewer(viewer_dir: str | Path, png: str | Path, mode: str | None = None, frame: str = "last",
                      size: tuple[int, int] = (900, 700), timeout: float = 120.0, live: LiveSource | None = None,
                      pose: dict[str, float] | None = None) -> str:
    """Load `viewer_dir` (from `write_viewer`) in headless Chromium with the given colouring
    (strain, pressure or plain; None: the page's default, strain, or the fabric for a
    network's animation or live posing) and frame, save a screenshot to `png` and return the page's
    status line ("ready: ..." when the scene was drawn). `live`: serve it with pose
    sliders (`start_server`), set to `pose` (degrees by slider name)."""
    from urllib.parse import urlencode

    if mode not in (None, "strain", "pressure", "plain"):
        raise TryonError(f"unknown viewer mode {mode!r}; use strain, pressure or plain")
    browser = find_browser()
    png = Path(png).resolve()
    server = start_server(viewer_dir, live=live)
    query = urlencode({**({"mode": mode} if mode else {}), "frame": frame, **(pose or {})})
    url = f"http://127.0.0.1:{server.server_address[1]}/index.html?{query}"
    try:
        with tempfile.TemporaryDirectory() as profile:
            shot = _chromium(browser, profile, size, [f"--screenshot={png}", url], timeout)
            if shot.returncode != 0 or not png.exists():
                raise TryonError(f"Chromium screenshot failed (exit {shot.returncode}): {shot.stderr[-500:]}")
        with tempfile.TemporaryDirectory() as profile:
            dom = _chromium(browser, profile, size, ["--dump-dom", url], timeout).stdout
    finally:
        server.shutdown()
    found = re.search(r'id="status"[^>]*>([^<]*)<', dom)
    return found.group(1).strip() if found else ""


def screenshot_url(url: str, png: str | Path, size: tuple[int, int] = (900, 800), timeout: float = 180.0) -> str:
    """Load `url` in headless Chromium, save a screenshot to `png`, and return the page's DOM
    as the browser left it (a second load: Chromium does one or the other per run)."""
    browser = find_browser()
    png = Path(png).resolve()
    with tempfile.TemporaryDirectory() as profile:
        shot = _chromium(browser, profile, size, [f"--screenshot={png}", url], timeout)
        if shot.returncode != 0 or not png.exists():
            raise TryonError(f"Chromium screenshot failed (exit {shot.returncode}): {shot.stderr[-500:]}")
    with tempfile.TemporaryDirectory() as profile:
        return _chromium(browser, profile, size, ["--dump-dom", url], timeout).stdout
