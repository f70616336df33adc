"""The daemon's HTTP API from Python (docs/openapi.yaml), with the standard library only."""

from __future__ import annotations

import json
import struct
import urllib.error
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


# ---- the world lifecycle API (a single daemon; docs/openapi.yaml "worlds") ----

class WorldError(Exception):
    """A refused world request: .status (HTTP), .field (the field it names), .message."""

    def __init__(self, status: int, message: str, field: str = ""):
        super().__init__(f"{status}: {message}")
        self.status = status
        self.message = message
        self.field = field


def _request(base: str, method: str, path: str, body: Any, token: str, timeout: float) -> Any:
    data = None if body is None else json.dumps(body, allow_nan=False).encode()
    req = urllib.request.Request(base.rstrip("/") + path, data=data, method=method)
    if data is not None:
        req.add_header("Content-Type", "application/json")
    if token:
        req.add_header("Authorization", f"Bearer {token}")
    try:
        with urllib.request.urlopen(req, timeout=timeout) as r:
            return json.loads(r.read())
    except urllib.error.HTTPError as e:
        try:
            doc = json.loads(e.read() or b"{}")
        except ValueError:
            doc = {}
        raise WorldError(e.code, doc.get("error", str(e)), doc.get("field", "")) from None


def create_world(base: str, name: str, scene: dict[str, Any] | None = None,
                 scene_name: str | None = None, token: str = "",
                 timeout: float = 120.0) -> dict[str, Any]:
    """POST /v1/worlds (admin): a world from a scene (an object, as in a scene file) or from
    scene_name (a scene of the daemon's --scene-dir). Returns the world's entry once it serves
    (hello with world=name to join it); raises WorldError naming the refused field."""
    body: dict[str, Any] = {"name": name}
    if scene is not None:
        body["scene"] = scene
    if scene_name is not None:
        body["scene_name"] = scene_name
    return _request(base, "POST", "/v1/worlds", body, token, timeout)


def list_worlds(base: str, token: str = "", timeout: float = 10.0) -> list[dict[str, Any]]:
    """GET /v1/worlds: every world (the default one first), each with name, state, tick..."""
    return _request(base, "GET", "/v1/worlds", None, token, timeout)["worlds"]


def delete_world(base: str, name: str, keep: bool = False, token: str = "",
                 timeout: float = 120.0) -> dict[str, Any]:
    """DELETE /v1/worlds/{name} (admin): its clients are closed (4020 "world deleted"), its
    storage removed, or kept for replays with keep=True."""
    return _request(base, "DELETE", f"/v1/worlds/{name}" + ("?keep=1" if keep else ""), None,
                    token, timeout)
