"""`tryon serve`: the try-on service (tryon.serve)."""

from __future__ import annotations

import argparse
import ipaddress
from pathlib import Path

from tryon.errors import TryonError


def _loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _cmd_serve(args: argparse.Namespace) -> int:
    import uvicorn

    from tryon.serve.app import Settings, create_app

    token = None
    if args.token_file:
        try:
            token = Path(args.token_file).read_text().strip()
        except OSError as exc:
            raise TryonError(f"--token-file {args.token_file}: {exc.strerror}") from exc
        if len(token) < 16:
            raise TryonError(f"--token-file {args.token_file}: the token must be at least 16 characters")
    if not _loopback(args.host) and token is None:
        raise TryonError(f"--host {args.host} is reachable from other machines: give --token-file with an API token")
    if (not 1 <= args.port <= 65535 or not 1 <= args.workers <= 64 or not 1 <= args.answer_workers <= 64
            or not 1 <= args.max_queue <= 100_000):
        raise TryonError("give a --port of 1-65535, 1-64 --workers and --answer-workers and a --max-queue of 1-100000")
    if args.ray_address:
        from tryon.parallel.executors import check_address

        check_address(args.ray_address)
    settings = Settings(Path(args.data), workers=args.workers, max_queue=args.max_queue,
                        time_limit_s=args.time_limit, retention_s=args.retention_hours * 3600.0, token=token,
                        answer_workers=args.answer_workers, ray_address=args.ray_address)
    where = f"Ray tasks on {args.ray_address}" if args.ray_address else "worker processes"
    print(f"tryon serve: http://{args.host}:{args.port}/docs (data: {settings.data}; {where}: {args.answer_workers} for "
          f"first answers, {args.workers} for refinement and simulation)")
    uvicorn.run(create_app(settings), host=args.host, port=args.port, log_level="warning")
    return 0


def add_commands(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("serve", help="the try-on service: an HTTP API for bodies and fits (OpenAPI at /docs)")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (not loopback: needs --token-file)")
    p.add_argument("--port", type=int, default=8000)
    p.add_argument("--data", default="tryon-data", help="folder for the database and the fits' files")
    p.add_argument("--workers", type=int, default=2,
                   help="workers that refine and simulate (at a lower priority than the first answers)")
    p.add_argument("--answer-workers", type=int, default=2,
                   help="workers that fit bodies and give first answers (every size predicted, a fraction of a "
                        "second each)")
    p.add_argument("--ray-address", help="run the jobs as Ray tasks on this cluster (started with `ray start`; its "
                                         "nodes must see --data)")
    p.add_argument("--max-queue", type=int, default=64, help="fits waiting or running before POST /v1/fits answers 429")
    p.add_argument("--time-limit", type=float, default=600.0, help="seconds a fit may run before it is failed")
    p.add_argument("--retention-hours", type=float, default=24.0, help="finished fits are kept this long")
    p.add_argument("--token-file", help="a file holding the API token every route but / asks for")
    p.set_defaults(func=_cmd_serve)
