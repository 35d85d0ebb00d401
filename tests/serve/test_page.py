"""The shopper's page in a real browser: headless Chromium (Debian's) loads it from a
running server, fills in a body, picks the T-shirt, waits for the recommendation, draws
the size in 3D and switches the colouring to ease; a screenshot is kept."""

import re
import shutil
import socket
import threading
import time
from pathlib import Path

import pytest

pytestmark = [pytest.mark.gl, pytest.mark.anny, pytest.mark.slow]


@pytest.fixture()
def server(tmp_path):
    import uvicorn

    from tryon.serve.app import Settings, create_app

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    srv = uvicorn.Server(uvicorn.Config(create_app(Settings(tmp_path / "data", workers=1)), host="127.0.0.1",
                                        port=port, log_level="warning"))
    thread = threading.Thread(target=srv.run, daemon=True)
    thread.start()
    t0 = time.time()
    while not srv.started and time.time() - t0 < 30:
        time.sleep(0.1)
    yield f"http://127.0.0.1:{port}"
    srv.should_exit = True
    thread.join(timeout=20)


def test_the_page_shows_the_size_in_3d_and_switches_to_ease(server, tmp_path):
    from tryon.viewer.screenshot import screenshot_url

    url = f"{server}/?auto=1&until=predicted&mode=ease&height_cm=180&weight_kg=78&gender=male&garment=tshirt"
    png = tmp_path / "page.png"
    dom = screenshot_url(url, png, size=(420, 1250))  # a phone-sized width
    status = re.search(r'id="status"[^>]*>([^<]*)<', dom).group(1)
    assert status.startswith("ready: size"), status
    assert "ease" in status
    share = float(re.search(r"(\d+) % of the view", status).group(1))
    assert share >= 5, status  # the canvas holds the body and garment, not a blank background
    assert re.search(r"Your size: (XS|S|M|L|XL|XXL)", dom)
    keep = Path(__file__).resolve().parents[2] / "out" / "page.png"
    keep.parent.mkdir(exist_ok=True)
    shutil.copyfile(png, keep)
