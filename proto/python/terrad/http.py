"""The daemon's HTTP API from Python (docs/openapi.yaml), with the standard library only."""

from __future__ import annotations

import json
import struct
import urllib.request
from typing import Any

from .client import HAVE_NUMPY, heights_grid


def _get(base: str, path: str, timeout: float) -> tuple[bytes, Any]:
    with urllib.request.urlopen(base.rstrip("/") + path, timeout=timeout) as r:
        return r.read(), r.headers


def get_heights(base: str, x: int, y: int, w: int, h: int, timeout: float = 10.0) -> tuple[int, Any]:
    """GET /v1/heights of a rectangle: (the tick it is the end of, heights_grid of it: a NumPy
    int32 array (h, w) or a list of rows)."""
    body, headers = _get(base, f"/v1/heights?x={x}&y={y}&w={w}&h={h}", timeout)
    if len(body) != 4 * w * h:
        raise ValueError(f"/v1/heights answered {len(body)} bytes for {w} x {h} cells")
    tick = int(headers["X-Terrad-Tick"])
    if HAVE_NUMPY:
        import numpy as np
        return tick, np.frombuffer(body, dtype="<i4").astype(np.int32).reshape(h, w)
    return tick, heights_grid(list(struct.unpack(f"<{w * h}i", body)), w, h)


def get_world(base: str, timeout: float = 10.0) -> dict[str, Any]:
    """GET /v1/world."""
    return json.loads(_get(base, "/v1/world", timeout)[0])


def get_stats(base: str, timeout: float = 10.0) -> dict[str, Any]:
    """GET /v1/stats."""
    return json.loads(_get(base, "/v1/stats", timeout)[0])
