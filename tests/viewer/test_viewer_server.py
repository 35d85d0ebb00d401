"""The viewer's server answers only on loopback, only to its own Host, and only with the
files `write_viewer` exported."""

import http.client
import json
from pathlib import Path

import numpy as np
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


class _FakeLive:
    """A live source of two garment vertices and one body vertex."""

    method = "fake"

    def controls(self):
        return [{"name": "arm_elevation.L", "label": "arm", "min": 0.0, "max": 90.0, "value": 45.0}]

    def frame(self, values):
        from tryon.errors import TryonError

        unknown = set(values) - {"arm_elevation.L"}
        if unknown:
            raise TryonError(f"unknown pose angle(s) {', '.join(unknown)}")   # echoes the request, as the real one
        a = values.get("arm_elevation.L", 45.0)
        if a == 13.0:
            raise RuntimeError("a bug")
        return {"garment": np.full((2, 3), a), "body": np.zeros((1, 3)), "strain": np.array([1.0, 2.0]), "ms": 3.5}


def _get_with_headers(port, url, headers):
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    conn.request("GET", url, headers={"Host": f"127.0.0.1:{port}", **headers})
    resp = conn.getresponse()
    return resp.status, dict(resp.getheaders()), resp.read()


def test_a_live_source_is_served_as_sliders_and_posed_frames(tmp_path):
    folder = _viewer_folder(tmp_path / "viewer")
    plain, live = start_server(folder), start_server(folder, live=_FakeLive())
    try:
        assert _get(plain.server_address[1], "/live.json")[0] == 404   # without --live there is no such page
        port = live.server_address[1]
        status, body = _get(port, "/live.json")
        assert status == 200 and json.loads(body)["controls"][0]["name"] == "arm_elevation.L"
        status, headers, body = _get_with_headers(port, "/live?arm_elevation.L=30", {})
        assert status == 200 and headers["X-Frame-Options"] == "DENY"
        assert np.frombuffer(body, "<f4").tolist() == [30.0] * 6 + [0.0] * 3 + [1.0, 2.0, 3.5]
        assert _get(port, "/live?tail=3")[0] == 400
        assert _get(port, "/live?arm_elevation.L=high")[0] == 400
        assert _get(port, "/live?arm_elevation.L=13")[0] == 500      # the source's own failure
        assert _get(port, "/live?arm_elevation.L=30", host=f"attacker.example:{port}")[0] == 403
        # another site's page may not drive it
        assert _get_with_headers(port, "/live?arm_elevation.L=30", {"Sec-Fetch-Site": "cross-site"})[0] == 403
    finally:
        plain.shutdown()
        live.shutdown()


def test_a_live_request_cannot_write_into_the_answers_headers(tmp_path):
    server = start_server(_viewer_folder(tmp_path / "viewer"), live=_FakeLive())
    port = server.server_address[1]
    try:
        status, headers, body = _get_with_headers(
            port, "/live?x%0d%0aContent-Type:%20text/html%0d%0a%0d%0a<script>alert(1)</script>=1", {})
        assert status == 400
        assert "<script>" not in body.decode() and all("\n" not in v and "\r" not in v for v in headers.values())
        assert _get(port, "/live?%E2%82%AC=1")[0] == 400              # not Latin-1: still an answer
    finally:
        server.shutdown()
