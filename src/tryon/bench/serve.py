"""`tryon bench serve`: the try-on service under load and faults, on loopback.

A real `tryon serve` runs in its own process on a fresh `--data`. S shoppers (threads,
each an HTTP client of the standard library) arrive one per `ARRIVAL_S` and, until the
run's end, each posts a body (a person drawn over the supported range), then a fit of
every T-shirt size, and follows it (`GET /v1/fits/{id}?wait=...`) to its first
recommendation (`predicted`) and on to `refined`, looks at it for `THINK_S`, then the
next person. Three runs:

- `fault: none`: `duration_s` of it; the service's figures.
- `fault: worker_killed`: a refinement worker and the first-answer worker are killed
  (SIGKILL) halfway.
- `fault: server_restarted`: the server process is killed (SIGKILL, a crash) halfway and
  started again on the same `--data`; shoppers retry what could not reach it.

After each run every fit the server acknowledged (202) is followed until it is done; a
fit not done within `DRAIN_S`, or gone, is a lost job. Keys per run: `shoppers`,
`duration_s`, `first_answer_p50_s`, `first_answer_p95_s` (from posting the body to the
first recommendation), `refined_p50_s`, `refined_p95_s`, `body_p50_s`, `requests_per_s`,
`fits_done`, `errors` (answers other than 2xx and 429, and fits that failed),
`lost_jobs`, `fault`. A probe of bad requests (`probe_bad_requests`) runs against the
same server: each must answer 4xx, its slowest answer is reported.
"""

from __future__ import annotations

import http.client
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tryon.errors import TryonError
from tryon.io.atomic import atomic_write
from tryon.io.json_safe import dumps_json

ARRIVAL_S = 1.0
THINK_S = (2.0, 8.0)  # a shopper looks at a refined answer this long (uniform) before the next person
DRAIN_S = 180.0
START_S = 120.0
DONE = ("refined", "simulated", "failed")


class Unreachable(Exception):
    """The server did not answer (down, restarting)."""


class Client:
    """A JSON client of one server; each call opens its own connection."""

    def __init__(self, port: int, timeout: float = 60.0):
        self.port, self.timeout = port, timeout

    def call(self, method: str, path: str, body: dict | None = None, headers: dict | None = None,
             raw: bytes | None = None, content_type: str = "application/json") -> tuple[int, dict, dict]:
        conn = http.client.HTTPConnection("127.0.0.1", self.port, timeout=self.timeout)
        try:
            payload = raw if raw is not None else (json.dumps(body).encode() if body is not None else None)
            hdrs = {"content-type": content_type, **(headers or {})} if payload is not None else dict(headers or {})
            conn.request(method, path, body=payload, headers=hdrs)
            r = conn.getresponse()
            data = r.read()
            try:
                parsed = json.loads(data) if data else {}
            except ValueError:
                parsed = {"raw": data[:200].decode(errors="replace")}
            return r.status, parsed, dict(r.getheaders())
        except (ConnectionError, socket.timeout, http.client.HTTPException, OSError) as exc:
            raise Unreachable(str(exc)) from exc
        finally:
            conn.close()


@dataclass
class Tally:
    """What the shoppers saw, shared between their threads."""

    first_s: list[float] = field(default_factory=list)
    refined_s: list[float] = field(default_factory=list)
    body_s: list[float] = field(default_factory=list)
    answer_s: list[float] = field(default_factory=list)  # from posting the fit to its first answer
    requests: int = 0
    errors: list[str] = field(default_factory=list)
    throttled: int = 0
    retries: int = 0
    fits: list[str] = field(default_factory=list)
    timings: list[dict] = field(default_factory=list)  # the server's own, per refined fit
    lock: threading.Lock = field(default_factory=threading.Lock)

    def add(self, name: str, value) -> None:
        with self.lock:
            getattr(self, name).append(value)


class Server:
    """`tryon serve` in a child process on a free loopback port."""

    def __init__(self, data: Path, workers: int, answer_workers: int, ray_address: str | None = None,
                 env: dict | None = None):
        self.data, self.workers, self.answer_workers = data, workers, answer_workers
        self.ray_address, self.env = ray_address, env
        data.mkdir(parents=True, exist_ok=True)
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            self.port = s.getsockname()[1]
        self.proc: subprocess.Popen | None = None
        self.log = open(data.parent / f"serve-{self.port}.log", "ab")

    def start(self) -> None:
        cmd = [sys.executable, "-m", "tryon.cli", "serve", "--port", str(self.port), "--data", str(self.data),
               "--workers", str(self.workers), "--answer-workers", str(self.answer_workers)]
        if self.ray_address:
            cmd += ["--ray-address", self.ray_address]
        self.proc = subprocess.Popen(cmd, stdout=self.log, stderr=self.log, start_new_session=True, env=self.env)
        client, t0 = Client(self.port, timeout=5.0), time.time()
        while time.time() - t0 < START_S:
            if self.proc.poll() is not None:
                raise TryonError(f"tryon serve stopped at start (exit {self.proc.returncode}); see {self.log.name}")
            try:
                code, health, _ = client.call("GET", "/health")
                if code == 200 and health.get("ready") and (self.ray_address or self._workers_ready(client)):
                    return
            except Unreachable:
                pass
            time.sleep(0.5)
        raise TryonError(f"tryon serve did not answer within {START_S:.0f} s; see {self.log.name}")

    @staticmethod
    def _workers_ready(client: Client) -> bool:
        pids = client.call("GET", "/metrics")[1].get("worker_pids", {})
        return all(pids.get(lane) for lane in ("answer", "work"))

    def worker_pids(self) -> dict[str, list[int]]:
        return Client(self.port, timeout=5.0).call("GET", "/metrics")[1]["worker_pids"]

    def crash(self) -> None:
        """SIGKILL the server and its workers (a crash: nothing is tidied up)."""
        os.killpg(self.proc.pid, signal.SIGKILL)
        self.proc.wait()

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self.crash()
        self.log.close()


def _person(rng: np.random.Generator) -> dict:
    gender = str(rng.choice(["female", "male"]))
    height = float(rng.uniform(155, 185) if gender == "female" else rng.uniform(165, 198))
    bmi = float(rng.uniform(18.5, 32))
    return {"height_cm": round(height, 1), "weight_kg": round(bmi * (height / 100) ** 2, 1), "gender": gender}


def _call(client: Client, tally: Tally, deadline: float, method: str, path: str, body: dict | None = None,
          key: str | None = None) -> tuple[int, dict] | None:
    """One request, retried while the server cannot be reached or answers 429 (until
    `deadline`); None when it never got through."""
    headers = {"Idempotency-Key": key} if key else None
    while time.time() < deadline:
        with tally.lock:
            tally.requests += 1
        try:
            status, data, hdrs = client.call(method, path, body, headers)
        except Unreachable:
            with tally.lock:
                tally.retries += 1
            time.sleep(0.5)
            continue
        if status == 429:
            with tally.lock:
                tally.throttled += 1
            time.sleep(float(hdrs.get("retry-after", hdrs.get("Retry-After", 1))))
            continue
        return status, data
    return None


def _shopper(port: int, seed: int, end: float, tally: Tally) -> None:
    client = Client(port)
    rng = np.random.default_rng([seed, 40])
    while time.time() < end:
        t0 = time.time()
        got = _call(client, tally, end + DRAIN_S, "POST", "/v1/bodies", _person(rng), key=uuid.uuid4().hex)
        if got is None or got[0] != 200:
            tally.add("errors", f"body: {got}")
            time.sleep(1.0)  # a shopper told no waits before trying again
            continue
        tally.add("body_s", time.time() - t0)
        t_fit = time.time()
        got = _call(client, tally, end + DRAIN_S, "POST", "/v1/fits", {"body_id": got[1]["body_id"], "garment": "tshirt"},
                    key=uuid.uuid4().hex)
        if got is None or got[0] != 202:
            tally.add("errors", f"fit: {got}")
            time.sleep(1.0)
            continue
        fit_id, status, answered = got[1]["fit_id"], "queued", False
        tally.add("fits", fit_id)
        while status not in DONE and time.time() < end + DRAIN_S:
            got = _call(client, tally, end + DRAIN_S, "GET", f"/v1/fits/{fit_id}?wait=20&after={status}")
            if got is None or got[0] != 200:
                tally.add("errors", f"poll {fit_id}: {got}")
                break
            status = got[1]["status"]
            if not answered and got[1].get("recommended"):
                answered = True
                tally.add("first_s", time.time() - t0)
                tally.add("answer_s", time.time() - t_fit)
        if status == "refined":
            tally.add("refined_s", time.time() - t0)
            tally.add("timings", got[1].get("timings", {}))
        elif status == "failed":
            tally.add("errors", f"fit {fit_id} failed: {got[1].get('reason') if got else '?'}")
        time.sleep(float(rng.uniform(*THINK_S)))


def _lost_jobs(port: int, fits: list[str]) -> tuple[int, list[str]]:
    """Fits acknowledged but not done within `DRAIN_S` (or gone)."""
    client, deadline, lost = Client(port), time.time() + DRAIN_S, []
    for fit_id in fits:
        status = None
        while time.time() < deadline:
            try:
                code, data, _ = client.call("GET", f"/v1/fits/{fit_id}?wait=20&after={status or 'queued'}")
            except Unreachable:
                time.sleep(1.0)
                continue
            status = data.get("status") if code == 200 else f"HTTP {code}"
            if status in DONE or code != 200:
                break
        if status not in DONE:
            lost.append(f"{fit_id}: {status}")
    return len(lost), lost


def _pct(values: list[float], q: float) -> float | None:
    return round(float(np.percentile(values, q)), 3) if values else None


def run_load(server: Server, shoppers: int, duration_s: float, fault: str = "none") -> dict:
    """S shoppers for `duration_s` against a started `server`, with `fault` halfway."""
    tally, t0 = Tally(), time.time()
    end = t0 + duration_s
    threads = []
    for i in range(shoppers):
        th = threading.Thread(target=_shopper, args=(server.port, i, end, tally), daemon=True)
        th.start()
        threads.append(th)
        time.sleep(min(ARRIVAL_S, duration_s / max(shoppers, 1) / 4))
    event = {}
    if fault != "none":
        time.sleep(max(0.0, t0 + duration_s / 2 - time.time()))
        event = _inject(server, fault)
    for th in threads:
        th.join(timeout=duration_s + 2 * DRAIN_S)
    wall = time.time() - t0
    lost, which = _lost_jobs(server.port, list(tally.fits))
    return {"fault": fault, "shoppers": shoppers, "duration_s": round(duration_s, 1), "wall_s": round(wall, 1),
            "first_answer_p50_s": _pct(tally.first_s, 50), "first_answer_p95_s": _pct(tally.first_s, 95),
            "refined_p50_s": _pct(tally.refined_s, 50), "refined_p95_s": _pct(tally.refined_s, 95),
            "body_p50_s": _pct(tally.body_s, 50), "body_p95_s": _pct(tally.body_s, 95),
            "fit_answer_p50_s": _pct(tally.answer_s, 50), "fit_answer_p95_s": _pct(tally.answer_s, 95),
            "requests_per_s": round(tally.requests / wall, 2),
            "fits_posted": len(tally.fits), "fits_done": len(tally.refined_s), "errors": len(tally.errors),
            "error_examples": tally.errors[:5], "throttled": tally.throttled, "retries": tally.retries,
            "lost_jobs": lost, "lost_examples": which[:5], **_server_timings(tally.timings), **event}


def _server_timings(timings: list[dict]) -> dict:
    """Medians and 95th percentiles of what the server says its phases took (s), and of
    how many sizes it refined."""
    keys = sorted({k for t in timings for k in t})
    return {f"server_{k}_p{q}": _pct([t[k] for t in timings if k in t], q) for k in keys for q in (50, 95)}


def _inject(server: Server, fault: str) -> dict:
    if fault == "worker_killed":
        pids = server.worker_pids()
        killed = [p for lane in ("work", "answer") for p in pids.get(lane, [])[:1]]
        for pid in killed:
            os.kill(pid, signal.SIGKILL)
        return {"killed_pids": killed}
    if fault == "server_restarted":
        t = time.time()
        server.crash()
        server.start()
        return {"restart_s": round(time.time() - t, 2)}
    raise ValueError(f"unknown fault {fault!r}")


def probe_bad_requests(port: int) -> dict:
    """Bad requests of every kind; each must answer 4xx. Returns the count, the slowest
    answer and any that did not answer 4xx."""
    c = Client(port, timeout=10.0)
    body = {"height_cm": 172, "weight_kg": 70, "gender": "male"}
    fake = "fit_0123456789abcdef"
    cases = [
        ("POST", "/v1/bodies", {"weight_kg": 70, "gender": "male"}, None), ("POST", "/v1/bodies", {**body, "height_cm": "x"}, None),
        ("POST", "/v1/bodies", {**body, "height_cm": 900}, None), ("POST", "/v1/bodies", {**body, "weight_kg": -5}, None),
        ("POST", "/v1/bodies", {**body, "gender": "robot"}, None), ("POST", "/v1/bodies", {**body, "extra": 1}, None),
        ("POST", "/v1/bodies", None, b"{not json"), ("POST", "/v1/bodies", None, b'{"height_cm": NaN}'),
        ("POST", "/v1/bodies", None, b"x" * (2 * 1024 * 1024)),
        ("POST", "/v1/fits", {"body_id": "body_0123456789abcdef"}, None),
        ("POST", "/v1/fits", {"body_id": "../../etc/passwd"}, None),
        ("POST", "/v1/fits", {"body_id": "body_0123456789abcdef", "garment": "cape"}, None),
        ("POST", "/v1/fits", {"body_id": "body_0123456789abcdef", "sizes": ["M", "M"]}, None),
        ("GET", f"/v1/fits/{fake}", None, None), ("GET", "/v1/fits/%2e%2e%2f%2e%2e%2fetc%2fpasswd", None, None),
        ("GET", f"/v1/fits/{fake}?wait=-1", None, None), ("GET", f"/v1/fits/{fake}?wait=1e9", None, None),
        ("GET", f"/v1/files/{fake}/..%2F..%2Ftryon.sqlite", None, None), ("GET", f"/v1/files/{fake}/x.glb%00.png", None, None),
        ("GET", "/static/..%2Fapp.py", None, None), ("GET", "/v1/nothing", None, None), ("DELETE", "/v1/bodies", None, None),
    ]
    slowest, wrong = 0.0, []
    for method, path, payload, raw in cases:
        t = time.perf_counter()
        try:
            code, data, _ = c.call(method, path, payload, raw=raw)
        except Unreachable as exc:
            code, data = 0, {"detail": str(exc)}
        slowest = max(slowest, time.perf_counter() - t)
        if not 400 <= code < 500:
            wrong.append(f"{method} {path[:60]}: {code} {str(data)[:120]}")
    # a fake image: the right type, not a picture
    boundary = uuid.uuid4().hex
    form = (f"--{boundary}\r\nContent-Disposition: form-data; name=\"height_cm\"\r\n\r\n175\r\n"
            f"--{boundary}\r\nContent-Disposition: form-data; name=\"gender\"\r\n\r\nmale\r\n"
            f"--{boundary}\r\nContent-Disposition: form-data; name=\"photos\"; filename=\"a.jpg\"\r\n"
            f"Content-Type: image/jpeg\r\n\r\nnot a jpeg\r\n--{boundary}--\r\n").encode()
    t = time.perf_counter()
    code, data, _ = c.call("POST", "/v1/bodies/photos", raw=form, content_type=f"multipart/form-data; boundary={boundary}")
    slowest = max(slowest, time.perf_counter() - t)
    if not 400 <= code < 500:
        wrong.append(f"fake photo: {code} {str(data)[:120]}")
    return {"bad_requests": len(cases) + 1, "slowest_answer_s": round(slowest, 3), "not_4xx": wrong}


def run_serve_bench(json_out: str, shoppers: int = 8, duration_s: float = 300.0, fault_duration_s: float = 90.0,
                    workers: int = 2, answer_workers: int = 2, faults: tuple[str, ...] = ("worker_killed", "server_restarted"),
                    data: str | None = None) -> dict:
    runs = []
    with tempfile.TemporaryDirectory(prefix="tryon-bench-serve-") as tmp:
        folder = Path(data) if data else Path(tmp)
        server = Server(folder / "data", workers, answer_workers)
        server.start()
        try:
            probe = probe_bad_requests(server.port)
            print(f"probe: {probe['bad_requests']} bad requests, slowest answer {probe['slowest_answer_s']} s, "
                  f"{len(probe['not_4xx'])} not 4xx", flush=True)
            for fault, seconds in [("none", duration_s), *[(f, fault_duration_s) for f in faults]]:
                print(f"{shoppers} shoppers for {seconds:.0f} s, fault: {fault} ...", flush=True)
                r = run_load(server, shoppers, seconds, fault)
                print(f"  first answer p50 {r['first_answer_p50_s']} s, p95 {r['first_answer_p95_s']} s; refined p95 "
                      f"{r['refined_p95_s']} s; {r['fits_done']} fits done; errors {r['errors']}; lost {r['lost_jobs']}",
                      flush=True)
                runs.append(r)
        finally:
            server.stop()
    out = {"bench": "serve", "machine": {"cpus": os.cpu_count()}, "workers": workers, "answer_workers": answer_workers,
           "think_s": list(THINK_S),
           "probe": probe, "runs": runs,
           "targets": {"first_answer_p95_s": 1.5, "refined_p95_s": 30.0, "errors": 0, "lost_jobs": 0}}
    with atomic_write(json_out) as fh:
        fh.write(dumps_json(out, indent=1))
    return out
