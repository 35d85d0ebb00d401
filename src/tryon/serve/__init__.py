"""`tryon serve`: the try-on service. An HTTP API (`app`) whose state is one SQLite database
and files under `--data` (`store`), fits run by worker processes (`dispatch`, `jobs`).
docs/SERVICE.md describes the API."""
