"""The viewer's server answers only on loopback, only to its own Host, and only with the
files `write_viewer` exported."""

import http.client
from pathlib import Path

import pytest

from tryon.errors import InputFileError
from tryon.viewer.export import SERVED_FILES, start_server


def _viewer_folder(path: Path) -> Path:
    path.mkdir()
    for name in SERVED_FILES:
        (path / name).write_text(f"content of {name}")
    (path / "secret.txt").write_text("not for the page")
    return path


def _get(port: int, url: str, host: str | None = None) -> tuple[int, bytes]:
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    conn.putrequest("GET", url, skip_host=True)
    conn.putheader("Host", host or f"127.0.0.1:{port}")
    conn.endheaders()
    resp = conn.getresponse()
    return resp.status, resp.read()


def test_serves_exported_files_only(tmp_path):
    server = start_server(_viewer_folder(tmp_path / "viewer"))
    port = server.server_address[1]
    try:
        assert server.server_address[0] == "127.0.0.1"
        assert _get(port, "/") == (200, b"content of index.html")
        assert _get(port, "/scene.json?x=1") == (200, b"content of scene.json")
        assert _get(port, "/", host=f"localhost:{port}")[0] == 200
        for url in ("/secret.txt", "/../secret.txt", "/%2e%2e/etc/passwd", "/viewer/", "//etc/passwd"):
            assert _get(port, url)[0] == 404, url
        assert _get(port, "/", host=f"attacker.example:{port}")[0] == 403  # DNS rebinding
        assert _get(port, "/", host="127.0.0.1")[0] == 403
    finally:
        server.shutdown()


def test_a_linked_or_incomplete_folder_is_refused(tmp_path):
    folder = _viewer_folder(tmp_path / "viewer")
    (folder / "scene.bin").unlink()
    (folder / "scene.bin").symlink_to(folder / "secret.txt")
    with pytest.raises(InputFileError, match="scene.bin"):
        start_server(folder)
