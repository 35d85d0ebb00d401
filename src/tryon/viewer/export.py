"""Write the web viewer for a drape (or one of its animations) and serve it locally.

`write_viewer(drape_dir)` puts into DIR/viewer/: index.html and viewer.js (the page),
three-bundle.min.js (three.js r187 with OrbitControls, MIT, see LICENSE-three.txt),
scene.json (titles, frame times, array layout) and scene.bin (garment and body
positions per frame as float32, faces as uint32, per-vertex strain in % per frame and
the contact pressure in kPa of the final drape). `serve(dir)` serves it on 127.0.0.1.
"""

from __future__ import annotations

import http.server
import json
import shutil
import sys
import threading
from importlib import resources
from pathlib import Path
from typing import Protocol

import numpy as np
import torch

from tryon.errors import InputFileError, TryonError
from tryon.io.atomic import atomic_output_dir, atomic_write
from tryon.io.json_safe import dumps_json
from tryon.io.packed import packed_layout, write_packed
from tryon.render.appearance import appearance

STATIC_FILES = ("index.html", "viewer.js", "meshes.js", "three-bundle.min.js", "LICENSE-three.txt")
SKIN = (0.80, 0.68, 0.60)


def vertex_strain_percent(positions: np.ndarray, faces: np.ndarray, corner_uv: np.ndarray) -> np.ndarray:
    """Per-vertex strain in % [T,N] (largest principal stretch - 1 of the faces around a
    vertex, averaged) for garment frames [T,N,3] with per-corner material coordinates."""
    from tryon.drape.outputs import face_to_vertex
    from tryon.sim.forces.geometry import rest_state
    from tryon.sim.metrics import principal_stretch

    F = len(faces)
    Dm_inv, _ = rest_state(torch.from_numpy(corner_uv.reshape(-1, 2)), torch.arange(3 * F).reshape(F, 3))
    ft = torch.from_numpy(faces)
    out = np.empty(positions.shape[:2], dtype=np.float32)
    for k, x in enumerate(positions):
        s = (principal_stretch(torch.from_numpy(np.ascontiguousarray(x)), ft, Dm_inv) - 1.0).numpy() * 100.0
        out[k] = face_to_vertex(faces, s, positions.shape[1])
    return out


def _load_sequence(drape_dir: Path, animation: str | None) -> dict:
    from tryon.drape.pipeline import STATE_FILE, load_state

    state = load_state(drape_dir / STATE_FILE)
    src = drape_dir if animation is None else drape_dir / f"animation-{animation}"
    path = src / "frames.npz"
    if not path.exists():
        hint = f"run `tryon animate {drape_dir} --motion {animation}` first" if animation else "run `tryon drape` again"
        raise InputFileError(f"{path} is missing; {hint}")
    d = np.load(path, allow_pickle=False)
    body = d["body_vertices"]
    return {
        "state": state,
        "positions": d["positions"],
        "times": d["times"] if "times" in d.files else np.arange(len(d["positions"]), dtype=float),
        "body": body[None] if body.ndim == 2 else body,
        "body_faces": d["body_faces"],
        "pressure": d["vertex_pressure"] / 1000.0 if animation is None and "vertex_pressure" in d.files else None,
        "report": json.loads((src / "report.json").read_text()) if (src / "report.json").exists() else {},
    }


def _title_and_info(seq: dict, animation: str | None) -> tuple[str, list[str]]:
    req = seq["state"]["request"]
    rep = seq["report"]
    body = req["body"]
    if req["garment"].lower().endswith(".obj"):
        title = f"{Path(req['garment']).name} in {req['fabric']}"
    else:
        title = f"{req['garment']} {req['size'] or 'made-to-measure'} in {req['fabric']}"
    who = f"{body['gender']}, {body['height_cm']:.0f} cm" + (f", {body['weight_kg']:.0f} kg" if body.get("weight_kg") else "")
    info = [who]
    if animation:
        info.append(f"motion: {animation}")
    if "ms_per_frame" in rep:
        info.append(f"predicted by {rep.get('method', 'a network')}: {rep['ms_per_frame']:.1f} ms per frame")
    if "max_strain" in rep:
        info.append(f"max strain {100 * rep['max_strain']:.1f} %, penetration {rep.get('penetration_pct', rep.get('max_penetration_pct', 0.0)):.2f} %")
    return title, info


def write_viewer(drape_dir: str | Path, animation: str | None = None, out: str | Path | None = None,
                 force: bool = False) -> Path:
    """Write the viewer for `drape_dir` (or its animation `animation`) and return its directory."""
    drape_dir = Path(drape_dir)
    seq = _load_sequence(drape_dir, animation)
    st = seq["state"]
    faces = st["faces"].astype(np.uint32)
    pos = seq["positions"].astype(np.float32)
    strain = vertex_strain_percent(seq["positions"], st["faces"], st["corner_uv"])
    arrays: list[tuple[str, np.ndarray]] = [("garment_positions", pos), ("garment_faces", faces), ("strain", strain),
                                            ("body_positions", seq["body"].astype(np.float32)),
                                            ("body_faces", seq["body_faces"].astype(np.uint32))]
    if seq["pressure"] is not None:
        arrays.append(("pressure", seq["pressure"].astype(np.float32)))
    layout = packed_layout(arrays)
    title, info = _title_and_info(seq, animation)
    meta = {
        "title": title, "info": info, "frames": int(len(pos)), "times": [float(t) for t in seq["times"]],
        "garment": {"vertices": int(pos.shape[1]), "positions": layout["garment_positions"], "faces": layout["garment_faces"],
                    "strain": layout["strain"], "pressure": layout.get("pressure")},
        "body": {"vertices": int(seq["body"].shape[1]), "frames": int(len(seq["body"])), "positions": layout["body_positions"],
                 "faces": layout["body_faces"]},
        "strain_max": float(max(10.0, np.percentile(strain, 99))),
        "pressure_max": float(max(0.5, np.percentile(seq["pressure"], 99))) if seq["pressure"] is not None else 1.0,
        "colors": {"skin": list(SKIN), "cloth": list(appearance(str(st["request"]["fabric"])).color)},
        # a network's prediction: its millimetres of noise read as several % of strain, so the fabric is shown first
        "predicted": "ms_per_frame" in seq["report"],
    }
    out = Path(out) if out is not None else drape_dir / ("viewer" if animation is None else f"viewer-{animation}")
    with atomic_output_dir(out, force=force) as tmp:
        for name in STATIC_FILES:
            with resources.as_file(resources.files("tryon.viewer").joinpath(f"static/{name}")) as src:
                shutil.copyfile(src, tmp / name)
        with atomic_write(tmp / "scene.json") as fh:
            fh.write(dumps_json(meta))
        write_packed(tmp / "scene.bin", arrays)
    return out


SERVED_FILES = (*STATIC_FILES, "scene.json", "scene.bin")
CONTENT_TYPES = {".html": "text/html; charset=utf-8", ".js": "text/javascript; charset=utf-8",
                 ".txt": "text/plain; charset=utf-8", ".json": "application/json", ".bin": "application/octet-stream"}


class LiveSource(Protocol):
    """What `tryon view --live` serves: sliders, and the scene in the pose they set."""

    method: str

    def controls(self) -> list[dict]: ...                     # name, label, min, max, value

    def frame(self, values: dict[str, float]) -> dict: ...    # garment [n,3], body [m,3], strain [n] (%), ms


class LiveRequestError(ValueError):
    """A live request the page should not have made (unknown or out-of-range angles)."""


def _live_answer(live: LiveSource, name: str, query: str) -> bytes:
    """`live.json`: the sliders. `live?NAME=DEG&...`: the posed scene as float32, garment
    positions, body positions, garment strain (%), then the prediction's milliseconds."""
    from urllib.parse import parse_qsl

    if name == "live.json":
        return dumps_json({"controls": live.controls(), "method": live.method}).encode()
    try:
        values = {k: float(v) for k, v in parse_qsl(query, strict_parsing=bool(query))}
    except ValueError as exc:
        raise LiveRequestError(f"the query is not NAME=DEGREES pairs ({exc})") from exc
    try:
        f = live.frame(values)
    except TryonError as exc:
        raise LiveRequestError(str(exc)) from exc
    parts = [np.asarray(f["garment"]).ravel(), np.asarray(f["body"]).ravel(), np.asarray(f["strain"]).ravel(),
             np.asarray([f["ms"]])]
    return np.concatenate(parts).astype("<f4").tobytes()


def _printable(text: str, limit: int = 300) -> str:
    """`text` as printable ASCII: it may echo a request's query (it goes only into the escaped
    body of an error page, and stays one line there)."""
    return "".join(c if " " <= c <= "~" else "?" for c in text)[:limit]


class _ViewerHandler(http.server.BaseHTTPRequestHandler):
    """Serves exactly the files `write_viewer` exported (read when the server starts), to
    requests whose Host header names this loopback server: no directory listings, no
    other files, no symbolic links, and no answers to a page that reached 127.0.0.1
    through another host name (DNS rebinding)."""

    files: dict[str, bytes] = {}
    allowed_hosts: frozenset[str] = frozenset()
    live: LiveSource | None = None

    def do_GET(self) -> None:  # noqa: N802 - the base class's name
        self._answer(with_body=True)

    def do_HEAD(self) -> None:  # noqa: N802
        self._answer(with_body=False)

    def _answer(self, with_body: bool) -> None:
        if self.headers.get("Host", "") not in self.allowed_hosts:
            self.send_error(403, "unexpected Host header")
            return
        path, _, query = self.path.split("#", 1)[0].partition("?")
        name = path.lstrip("/") or "index.html"
        body = self.files.get(name)
        if body is None and self.live is not None and name in ("live.json", "live"):
            if self.headers.get("Sec-Fetch-Site", "same-origin") not in ("same-origin", "none"):
                self.send_error(403, "live poses are for this viewer's own page")
                return
            try:
                body = _live_answer(self.live, name, query)
            except LiveRequestError as exc:   # the explanation goes in the (escaped) body, never in a header
                self.send_error(400, "bad live request", _printable(str(exc)))
                return
            except Exception as exc:  # noqa: BLE001 - the page gets an answer; the terminal gets the cause
                print(f"tryon view: a live pose failed: {exc!r}", file=sys.stderr, flush=True)
                self.send_error(500, "the live pose failed (see the terminal)")
                return
        if body is None:
            self.send_error(404)
            return
        self.send_response(200)
        self.send_header("X-Frame-Options", "DENY")
        self.send_header("Content-Type", CONTENT_TYPES.get(Path(name).suffix, "application/octet-stream"))
        self.send_header("Cache-Control", "no-store")
        self.send_header("Content-Length", str(len(body)))
        self.send_header("X-Content-Type-Options", "nosniff")
        self.end_headers()
        if with_body:
            self.wfile.write(body)

    def log_message(self, format, *args):  # noqa: A002 - the base class's name
        pass


def _exported_files(directory: Path) -> dict[str, bytes]:
    files = {}
    for name in SERVED_FILES:
        path = directory / name
        if path.is_symlink() or not path.is_file():
            raise InputFileError(f"{directory} is not a viewer folder written by tryon ({name} is missing or a link); "
                                 "run `tryon view DRAPE_DIR` to write it")
        files[name] = path.read_bytes()
    return files


def start_server(directory: str | Path, port: int = 0, live: LiveSource | None = None) -> http.server.ThreadingHTTPServer:
    """An HTTP server for the viewer in `directory` on 127.0.0.1 only (port 0: any free
    port), running in a background thread; call `.shutdown()` to stop it. `live`: a source
    of posed frames, which the page then offers as pose sliders (`live.json`, `live?...`)."""
    files = _exported_files(Path(directory))
    handler = type("ViewerHandler", (_ViewerHandler,), {"files": files, "live": live})
    server = http.server.ThreadingHTTPServer(("127.0.0.1", port), handler)
    bound = server.server_address[1]
    handler.allowed_hosts = frozenset({f"127.0.0.1:{bound}", f"localhost:{bound}"})
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server
