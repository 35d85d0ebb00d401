"""The HTTP API (FastAPI): bodies, fits and their files, health and metrics.

`create_app(settings)` builds it; `tryon serve` runs it on uvicorn. Requests are checked
by schema (a 422 names the field), a full queue answers 429 with Retry-After, POSTs with
an `Idempotency-Key` header answer the same twice, and files are served only from the
fit's own folder under `--data`.
"""

from __future__ import annotations

import asyncio
import re
import secrets
import shutil
import threading
import time
from contextlib import asynccontextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from fastapi import FastAPI, File, Form, Header, HTTPException, Query, Request, UploadFile
from fastapi.concurrency import run_in_threadpool
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, JSONResponse
from pydantic import BaseModel, ConfigDict, Field, field_validator

from tryon.errors import TryonError
from tryon.garment.drafts import GARMENTS
from tryon.garment.sizes import SIZES
from tryon.serve.dispatch import Dispatcher
from tryon.serve.bodies import fit_and_save_body, quick_body, save_body
from tryon.serve.jobs import body_path, first_phase, fit_folder
from tryon.serve.store import DONE, Store, new_id

API_VERSION = "v1"
ID = {"body": re.compile(r"^body_[0-9a-f]{16}$"), "fit": re.compile(r"^fit_[0-9a-f]{16}$")}
FILE_NAME = re.compile(r"^[A-Za-z0-9_-]{1,64}(\.glb|-fit_map\.png|-scene\.json|-scene\.bin)$")
MEDIA = {".glb": "model/gltf-binary", ".png": "image/png", ".json": "application/json", ".bin": "application/octet-stream"}


@dataclass
class Settings:
    data: Path
    workers: int = 1
    max_queue: int = 64
    time_limit_s: float = 600.0
    retention_s: float = 24 * 3600.0
    token: str | None = None
    answer_workers: int = 1
    ray_address: str | None = None


class BodyIn(BaseModel):
    """A shopper's numbers (cm, kg, years)."""

    model_config = ConfigDict(extra="forbid")
    height_cm: float = Field(ge=140, le=210)
    weight_kg: float = Field(ge=25, le=250)
    gender: Literal["female", "male"]
    age: float = Field(30.0, ge=16, le=90)
    chest_cm: float | None = Field(None, ge=65, le=160)
    waist_cm: float | None = Field(None, ge=50, le=160)
    hip_cm: float | None = Field(None, ge=70, le=170)


class FitIn(BaseModel):
    model_config = ConfigDict(extra="forbid")
    body_id: str = Field(pattern=ID["body"].pattern)
    garment: Literal[GARMENTS] = "tshirt"  # type: ignore[valid-type]
    fabric: str = Field("gray-interlock", max_length=64)
    sizes: list[Literal[SIZES]] | None = Field(None, min_length=1, max_length=len(SIZES))  # type: ignore[valid-type]

    @field_validator("fabric")
    @classmethod
    def _preset(cls, v: str) -> str:
        from tryon.fabric.presets import list_presets

        if v not in list_presets():
            raise ValueError(f"unknown fabric {v!r}; presets: {', '.join(list_presets())}")
        return v

    @field_validator("sizes")
    @classmethod
    def _distinct(cls, v):
        if v is not None and len(set(v)) != len(v):
            raise ValueError("give each size once")
        return v


def _fit_view(store: Store, fit_id: str) -> dict:
    row = store.fit(fit_id)
    if row is None:
        raise HTTPException(404, f"no fit {fit_id}")
    out = {"fit_id": row.id, "body_id": row.body_id, "status": row.status, "progress": round(row.progress, 3),
           "garment": row.request["garment"], "fabric": row.request["fabric"], "recommended": None, "reasons": [],
           "sizes": []}
    if row.result:
        out.update({k: row.result[k] for k in ("recommended", "reasons", "sizes", "method", "notes", "timings") if k in row.result})
    if row.status == "failed":
        out["reason"] = row.reason
    return out


def create_app(settings: Settings) -> FastAPI:
    settings.data.mkdir(parents=True, exist_ok=True)
    store = Store(settings.data / "tryon.sqlite")
    dispatcher = Dispatcher(store, settings.data, settings.workers, settings.time_limit_s, settings.retention_s,
                            settings.answer_workers, settings.ray_address)
    started = time.time()
    ready = threading.Event()  # set once the body model is loaded here (GET /health: `ready` once the workers are warm too)

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        app.state.recovered = store.recover()
        dispatcher.start()
        if settings.workers > 0:  # the body model loaded before the first shopper waits for it
            threading.Thread(target=_warm_up_bodies, args=(ready,), name="tryon-warm-up", daemon=True).start()
        else:
            ready.set()
        yield
        dispatcher.close()

    app = FastAPI(title="tryon", version=API_VERSION, lifespan=lifespan,
                  description="Virtual try-on: a body from a shopper's numbers, every size of a garment draped and "
                              "judged on it.")
    app.state.store, app.state.dispatcher = store, dispatcher

    @app.middleware("http")
    async def _token(request: Request, call_next):
        if settings.token and request.url.path != "/":
            given = request.headers.get("authorization", "")
            if not secrets.compare_digest(given.encode(), f"Bearer {settings.token}".encode()):
                return JSONResponse({"detail": "give the API token: Authorization: Bearer <token>"}, status_code=401)
        return await call_next(request)

    @app.exception_handler(RequestValidationError)
    async def _invalid(request: Request, exc: RequestValidationError):
        problems = [f"{'.'.join(str(p) for p in e['loc'] if p != 'body') or 'body'}: {e['msg']}" for e in exc.errors()]
        return JSONResponse({"detail": "; ".join(problems)}, status_code=422)

    async def _once(key: str | None, route: str, make) -> dict:
        """`await make()`'s response, or the response given before to a POST with the
        same `Idempotency-Key` (409 when the key was used on the other route)."""
        if key is not None:
            if len(key) > 128:
                raise HTTPException(422, "Idempotency-Key: at most 128 characters")
            seen = store.remembered(key, route)
            if seen and "conflict" in seen:
                raise HTTPException(409, f"Idempotency-Key {key!r} was used for {seen['conflict']}")
            if seen:
                return seen
        response = await make()
        if key is not None:
            store.remember(key, route, response)
        return response

    def _keep_body(fit, request: dict, result: dict) -> dict:
        """A fitted body stored for its fits; the API's answer."""
        body_id = new_id("body")
        save_body(fit, body_path(settings.data, body_id))
        store.add_body(request, result, body_id)
        return {"body_id": body_id, **result}

    async def _fit_body(request: dict) -> dict:
        """The quick body fit of `request`, saved; by an answer worker when one is free to
        take it (the fit is torch work that would hold this process's other requests),
        else in a thread here. Returns the API's answer."""
        body_id = new_id("body")
        path = str(body_path(settings.data, body_id))
        fut = dispatcher.call(fit_and_save_body, request, path)
        result = None
        if fut is not None:
            try:
                result = await asyncio.wrap_future(fut)
            except TryonError:
                raise
            except Exception:  # noqa: BLE001 - the worker died under it: fit it here instead
                result = None
            except asyncio.CancelledError:
                if not fut.cancelled():  # the request itself was cancelled
                    raise
                result = None  # the pool was replaced before the fit started
        if result is None:
            result = await run_in_threadpool(fit_and_save_body, request, path)
        store.add_body(request, result, body_id)
        return {"body_id": body_id, **result}

    @app.post(f"/{API_VERSION}/bodies")
    async def post_body(body: BodyIn, idempotency_key: str | None = Header(None)) -> dict:
        """The shopper's body: measurements of the fitted Anny body, and warnings."""
        async def make() -> dict:
            from tryon.body.fit import Measurements

            request = body.model_dump(exclude_none=True)
            try:
                Measurements(**request).validate()
                return await _fit_body(request)
            except TryonError as exc:
                raise HTTPException(422, str(exc)) from exc

        return await _once(idempotency_key, "bodies", make)

    @app.post(f"/{API_VERSION}/bodies/photos")
    async def post_body_photos(photos: list[UploadFile] = File(...), height_cm: float = Form(..., ge=140, le=210),
                               gender: Literal["female", "male"] = Form(...),
                               weight_kg: float | None = Form(None, ge=25, le=250), age: float = Form(30.0, ge=16, le=90),
                               idempotency_key: str | None = Header(None)) -> dict:
        """The shopper's body from 1-4 photos (front, side, back; JPEG, PNG or WebP, at most
        10 MB each) with their height and gender (weight optional): measurements read off
        the photos, each with its spread."""
        async def make() -> dict:
            if not 1 <= len(photos) <= MAX_PHOTOS:
                raise HTTPException(422, f"photos: give 1 to {MAX_PHOTOS} photos, got {len(photos)}")
            folder = settings.data / "uploads" / new_id("up")
            paths: list[Path] = []
            try:
                for i, photo in enumerate(photos):
                    paths.append(await _save_upload(photo, folder, i))
                pb = await run_in_threadpool(_photo_body, paths, height_cm, gender, weight_kg, age)
            except TryonError as exc:  # named by the shopper's file names, never the server's paths
                message = str(exc)
                for i, (path, photo) in enumerate(zip(paths, photos)):
                    message = message.replace(str(path), f"photo {i + 1} ({photo.filename})")
                raise HTTPException(422, message.replace(str(folder), "upload")) from exc
            finally:
                shutil.rmtree(folder, ignore_errors=True)  # photos are not kept
            request = {k: v for k, v in vars(pb.request()).items() if v is not None}
            return _keep_body(pb.fit, request, {"measurements": pb.measurements(), "warnings": list(pb.notes),
                                                "fit_s": round(pb.timings["total_s"], 3),
                                                "source": f"{len(paths)} photo(s)"})

        return await _once(idempotency_key, "bodies", make)

    @app.post(f"/{API_VERSION}/fits", status_code=202)
    async def post_fit(fit: FitIn, idempotency_key: str | None = Header(None)) -> dict:
        """Every size of a garment on a body: answers at once with the fit's id; follow it
        with GET /v1/fits/{fit_id}."""
        async def make() -> dict:
            if store.body(fit.body_id) is None:
                raise HTTPException(404, f"no body {fit.body_id}; make one with POST /{API_VERSION}/bodies")
            if store.waiting() >= settings.max_queue:
                raise HTTPException(429, f"the queue is full ({settings.max_queue} fits waiting); try again shortly",
                                    headers={"Retry-After": "5"})
            fit_id = store.add_fit(fit.body_id, fit.model_dump(), first_phase(fit.garment))
            dispatcher.notify()
            return {"fit_id": fit_id, "body_id": fit.body_id, "status": "queued", "progress": 0.0, "recommended": None,
                    "sizes": []}

        return await _once(idempotency_key, "fits", make)

    @app.get(f"/{API_VERSION}/fits/{{fit_id}}")
    async def get_fit(fit_id: str, wait: float = Query(0.0, ge=0, le=30),
                      after: Literal["queued", "running", "predicted"] | None = None) -> dict:
        """The fit as it stands. With `wait` (s) and `after` (a status): answers as soon as
        the status differs from `after`, or after `wait` seconds (long polling)."""
        if not ID["fit"].match(fit_id):
            raise HTTPException(404, f"no fit {fit_id[:40]!r}: fit ids look like fit_0123456789abcdef")
        seen, read_at = dispatcher.generation, time.monotonic()  # read before the fit: no move is missed
        view = _fit_view(store, fit_id)
        deadline = time.monotonic() + wait
        while after is not None and view["status"] == after and time.monotonic() < deadline:
            await asyncio.sleep(0.02)
            # read the fit again when the dispatcher saw a job move (or once a second in any case)
            if dispatcher.generation != seen or time.monotonic() - read_at > 1.0:
                seen, read_at = dispatcher.generation, time.monotonic()
                view = _fit_view(store, fit_id)
        return view

    @app.get(f"/{API_VERSION}/catalog")
    async def catalog() -> dict:
        """What can be tried on: garments (and whether a learned model answers at once),
        fabrics, sizes."""
        from tryon.fabric.presets import list_presets
        from tryon.serve.jobs import learned_garment

        labels = {"tshirt": "T-shirt", "longsleeve": "long-sleeve top", "trousers": "trousers", "skirt": "skirt",
                  "dress": "dress"}
        return {"garments": [{"name": g, "label": labels.get(g, g), "learned": learned_garment(g)} for g in GARMENTS],
                "fabrics": list_presets(), "sizes": list(SIZES)}

    @app.get("/", include_in_schema=False)
    async def page():
        return FileResponse(_static("index.html"), media_type="text/html")

    @app.get("/static/{name}", include_in_schema=False)
    async def static(name: str):
        if name not in STATIC:
            raise HTTPException(404, "no such file")
        return FileResponse(_static(name), media_type="text/javascript")

    @app.get(f"/{API_VERSION}/files/{{fit_id}}/{{name}}")
    async def get_file(fit_id: str, name: str):
        if not ID["fit"].match(fit_id) or not FILE_NAME.match(name):
            raise HTTPException(404, "no such file")
        root = fit_folder(settings.data, fit_id).resolve()
        path = (root / name).resolve()
        if path.parent != root or not path.is_file():
            raise HTTPException(404, "no such file")
        return FileResponse(path, media_type=MEDIA[path.suffix])

    @app.get("/health")
    async def health() -> dict:
        return {"ok": True, "ready": ready.is_set() and dispatcher.ready(), "workers": settings.workers,
                "waiting": store.waiting()}

    @app.get("/metrics")
    async def metrics() -> dict:
        return {"fits": store.counts(), "uptime_s": round(time.time() - started, 1), "workers": settings.workers,
                "worker_pids": dispatcher.worker_pids(), "events": dispatcher.events,
                "recovered_at_start": getattr(app.state, "recovered", {}), "done_states": list(DONE)}

    return app


# the page's files: its own, and three.js from the viewer's
STATIC = {"page.js": "tryon.serve", "meshes.js": "tryon.viewer", "three-bundle.min.js": "tryon.viewer"}


def _static(name: str) -> Path:
    from importlib import resources

    package = STATIC.get(name, "tryon.serve")
    return Path(str(resources.files(package).joinpath(f"static/{name}")))


MAX_PHOTOS = 4
MAX_UPLOAD_BYTES = 10 * 1024 * 1024
PHOTO_TYPES = {"image/jpeg": ".jpg", "image/png": ".png", "image/webp": ".webp"}


async def _save_upload(photo: UploadFile, folder: Path, i: int) -> Path:
    """An uploaded photo written to `folder`, refused when it is not a picture type or too big."""
    suffix = PHOTO_TYPES.get((photo.content_type or "").split(";")[0].strip().lower())
    if suffix is None:
        raise HTTPException(415, f"photo {i + 1} ({photo.filename!r}): send JPEG, PNG or WebP, not {photo.content_type!r}")
    data = await photo.read(MAX_UPLOAD_BYTES + 1)
    if len(data) > MAX_UPLOAD_BYTES:
        raise HTTPException(413, f"photo {i + 1} ({photo.filename!r}) is over {MAX_UPLOAD_BYTES // 2**20} MB")
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"photo-{i + 1}{suffix}"
    path.write_bytes(data)
    return path


def _photo_body(paths, height_cm, gender, weight_kg, age):
    from tryon.learn.body_from_photos import body_from_image_files

    return body_from_image_files([str(p) for p in paths], height_cm, gender, weight_kg, age)


def _warm_up_bodies(ready: threading.Event) -> None:
    """Load the body model here too: a body fit falls back to a thread of this process
    when its worker fails."""
    try:
        quick_body({"height_cm": 170.0, "weight_kg": 65.0, "gender": "female"})
    except Exception:  # noqa: BLE001 - a real request will report what is wrong
        pass
    finally:
        ready.set()
