"""The twin library (libterrad-twin, docs/engines.md) from Python, through ctypes: the
daemon's CPU twin run on a client's own window, heights bit for bit the server's. Its
prediction (terrad_twin_prediction_*, the one copy every client runs) is what terrad.predict
calls.

    from terrad.twin import Twin
    twin = Twin({"width": 256, "height": 256, "terrain.height_m": 0.4}, 96, 96, 64, 64)
    twin.add_collider(1, "sphere", radius=0.3)
    twin.set_pose(1, (5.5, 6.4, 0.65))
    twin.tick()
    heights = twin.read()          # array('i'), 64 * 64 row-major, height units

The library is found, in this order: the `library` argument, $TERRAD_TWIN_LIBRARY, the
system's linker path (`make install`: libterrad-twin.so.1), and the build tree beside this
package in a source checkout (build/libterrad-twin.so). Every refusal of the C API raises
TwinError with the library's sentence, which names the field; the twin goes on working.
"""

from __future__ import annotations

import array
import ctypes
import ctypes.util
import os
from collections.abc import Sequence
from typing import Any

_ERR_MAX = 256  # TERRAD_TWIN_ERROR_MAX
_LIBRARY: ctypes.CDLL | None = None


class TwinError(ValueError):
    """A call of the twin library refused its input; the message names the field."""


def _candidates() -> list[str]:
    found = [os.environ.get("TERRAD_TWIN_LIBRARY", "")]
    for name in ("libterrad-twin.so.1", "libterrad-twin.so"):
        found.append(name)  # the dynamic linker's path: an installed library
    system = ctypes.util.find_library("terrad-twin")
    if system:
        found.append(system)
    here = os.path.dirname(os.path.abspath(__file__))
    found.append(os.path.join(here, "..", "..", "..", "build", "libterrad-twin.so"))
    return [c for c in found if c]


class PredictionStats(ctypes.Structure):
    """terrad_twin_prediction_stats (terrad_twin.h)."""
    _fields_ = [(name, ctypes.c_uint64) for name in (
        "predicted", "reconciled", "replayed", "exact", "skipped", "on_time", "last_differing",
        "pending")]


def _declare(lib: ctypes.CDLL) -> ctypes.CDLL:
    P, I, D, S = ctypes.c_void_p, ctypes.c_int, ctypes.c_double, ctypes.c_char_p
    U32, U64 = ctypes.c_uint32, ctypes.c_uint64
    i32p, u32p = ctypes.POINTER(ctypes.c_int32), ctypes.POINTER(ctypes.c_uint32)
    f32p, dp = ctypes.POINTER(ctypes.c_float), ctypes.POINTER(ctypes.c_double)
    sigs: dict[str, tuple[Any, list[Any]]] = {
        "config_new": (P, []),
        "config_free": (None, [P]),
        "config_set": (I, [P, S, D, S]),
        "config_set_name": (I, [P, S, S, S]),
        "create": (P, [P, I, I, I, I, i32p, S]),
        "destroy": (None, [P]),
        "add_collider": (I, [P, I, S, D, D, D, D, D, S]),
        "add_wheel": (I, [P, I, D, D, D, D, D, S]),
        "add_mesh": (I, [P, I, ctypes.POINTER(ctypes.c_float), I,
                         ctypes.POINTER(ctypes.c_uint32), I, S]),
        "remove_collider": (I, [P, I, S]),
        "set_pose": (I, [P, I, D, D, D, D, D, D, D, S]),
        "place": (I, [P, I, D, D, D, D, D, D, D, S]),
        "set_load": (I, [P, I, D, S]),
        "tick": (I, [P, S]),
        "read": (I, [P, I, I, I, I, i32p, S]),
        "write": (I, [P, I, I, I, I, i32p, S]),
        "prediction_create": (P, [P, I, I, I, I, i32p, I, S]),
        "prediction_destroy": (None, [P]),
        "prediction_add_collider": (I, [P, U32, S, D, D, D, D, D, S]),
        "prediction_add_wheel": (I, [P, U32, D, D, D, D, D, S]),
        "prediction_add_mesh": (I, [P, U32, f32p, I, u32p, I, S]),
        "prediction_set_load": (I, [P, U32, D, S]),
        "prediction_remove_collider": (I, [P, U32, S]),
        "prediction_sent": (I, [P, U32, u32p, dp, I, S]),
        "prediction_acked": (I, [P, U64, U32, i32p, S]),
        "prediction_resume": (I, [P, U64, u32p, dp, I, S]),
        "prediction_get_stats": (ctypes.POINTER(PredictionStats), [P]),
        "prediction_pending": (I, [P, u32p, I]),
        "prediction_twin": (P, [P]),
    }
    for name, (res, args) in sigs.items():
        f = getattr(lib, "terrad_twin_" + name)
        f.restype, f.argtypes = res, args
    return lib


def load_library(path: str | None = None) -> ctypes.CDLL:
    """The twin library (see the module's text for where it is looked for); OSError naming
    every place tried when none loads."""
    global _LIBRARY
    if path is None and _LIBRARY is not None:
        return _LIBRARY
    tried = []
    for c in [path] if path else _candidates():
        try:
            lib = _declare(ctypes.CDLL(c))
        except (OSError, AttributeError) as e:
            tried.append(f"{c}: {e}")
            continue
        if path is None:
            _LIBRARY = lib
        return lib
    raise OSError("the twin library libterrad-twin was not found (make build, or make install; "
                  "or set TERRAD_TWIN_LIBRARY): " + "; ".join(tried))


def int32s(values: Sequence[int] | Any, n: int, what: str) -> Any:
    flat = values.ravel().tolist() if hasattr(values, "ravel") else values
    try:
        buf = array.array("i", flat)
    except (TypeError, OverflowError) as e:
        raise TwinError(f"{what}: must be int32 height units ({e})") from e
    if len(buf) != n:
        raise TwinError(f"{what}: {len(buf)} values for {n} cells")
    return (ctypes.c_int32 * n).from_buffer(buf)


def grouser_numbers(grousers: dict[str, Any] | None) -> tuple[float, float, float]:
    """A wheel's {"count", "height", "thickness"} (PROTOCOL.md collider_create "grousers") as
    the library's three numbers; None: a smooth rim (0, 0, 0). The library judges the values
    and names the field (grousers.count, .height, .thickness); here only their form."""
    if grousers is None:
        return 0.0, 0.0, 0.0
    keys = ("count", "height", "thickness")
    if not isinstance(grousers, dict) or set(grousers) != set(keys):
        raise TwinError(f"grousers: must be {{count, height, thickness}}, not {grousers!r}")
    out = []
    for k in keys:
        v = grousers[k]
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise TwinError(f"grousers.{k}: must be a number, not {type(v).__name__}")
        out.append(float(v))
    return out[0], out[1], out[2]


def make_config(lib: ctypes.CDLL, config: dict[str, Any], err: Any) -> int:
    """A terrad_twin_config from {key: number or name}; the caller frees it
    (terrad_twin_config_free). TwinError naming the key on a refusal."""
    cfg = lib.terrad_twin_config_new()
    if not cfg:
        raise MemoryError("terrad_twin_config_new")
    try:
        for key, value in config.items():
            if isinstance(value, str):
                rc = lib.terrad_twin_config_set_name(cfg, key.encode(), value.encode(), err)
            elif isinstance(value, (int, float)) and not isinstance(value, bool):
                rc = lib.terrad_twin_config_set(cfg, key.encode(), float(value), err)
            else:
                raise TwinError(f"{key}: must be a number or a name, not {type(value).__name__}")
            if rc != 0:
                raise TwinError(err.value.decode(errors="replace"))
    except BaseException:
        lib.terrad_twin_config_free(cfg)
        raise
    return cfg


class Twin:
    """One window of the world in the twin library. Not thread-safe: one thread's at a time."""

    def __init__(self, config: dict[str, Any], x: int, y: int, w: int, h: int,
                 heights: Sequence[int] | None = None, library: str | None = None):
        """config: the world's parameters under the twin's keys (terrad_twin.h: width,
        height, cell_size_m, units_per_m, model, compression, terrain.kind, ...), a number or
        a name each. heights: w * h row-major (the server's), or None for the base terrain."""
        self._lib = load_library(library)
        self._t: int | None = None
        self._owned = True
        self.x, self.y, self.w, self.h = x, y, w, h
        err = ctypes.create_string_buffer(_ERR_MAX)
        cfg = make_config(self._lib, config, err)
        try:
            buf = None if heights is None else int32s(heights, w * h, "heights")
            t = self._lib.terrad_twin_create(cfg, x, y, w, h, buf, err)
        finally:
            self._lib.terrad_twin_config_free(cfg)
        if not t:
            raise TwinError(err.value.decode(errors="replace"))
        self._t = t
        self._err = err

    @classmethod
    def view(cls, lib: ctypes.CDLL, handle: int, x: int, y: int, w: int, h: int) -> Twin:
        """A twin another object owns (a Prediction's): read and written here, never
        destroyed here."""
        t = cls.__new__(cls)
        t._lib, t._t, t._owned = lib, handle, False
        t.x, t.y, t.w, t.h = x, y, w, h
        t._err = ctypes.create_string_buffer(_ERR_MAX)
        return t

    def _check(self, rc: int) -> None:
        if rc != 0:
            raise TwinError(self._err.value.decode(errors="replace"))

    def _handle(self) -> int:
        if self._t is None:
            raise TwinError("twin: closed")
        return self._t

    def close(self) -> None:
        if self._t is not None and self._owned:
            self._lib.terrad_twin_destroy(self._t)
        self._t = None

    def __del__(self) -> None:
        self.close()

    def __enter__(self) -> Twin:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def add_collider(self, cid: int, shape: str, radius: float = 0.0, half_length: float = 0.0,
                     half_extents: Sequence[float] = (0.0, 0.0, 0.0)) -> None:
        """sphere (radius), box (half_extents), capsule / cylinder (radius, half_length; the
        axis is the collider's local y, as a wheel's axle)."""
        hx, hy, hz = half_extents
        self._check(self._lib.terrad_twin_add_collider(self._handle(), cid, shape.encode(),
                                                       radius, half_length, hx, hy, hz,
                                                       self._err))

    def add_wheel(self, cid: int, radius: float, half_length: float,
                  grousers: dict[str, Any] | None = None) -> None:
        """A cylinder (axle: local y) with grousers {"count": N, "height": m, "thickness": m}
        on its rim, as the server presses them; None: smooth."""
        self._check(self._lib.terrad_twin_add_wheel(self._handle(), cid, radius, half_length,
                                                    *grouser_numbers(grousers), self._err))

    def set_load(self, cid: int, load_n: float) -> None:
        """Load-driven (bekker worlds): each tick the height where the soil carries load_n
        newtons, found as the server finds it (terrad_twin_set_load); 0: pose-driven."""
        self._check(self._lib.terrad_twin_set_load(self._handle(), cid, float(load_n),
                                                   self._err))

    def add_mesh(self, cid: int, vertices: Sequence[float], indices: Sequence[int]) -> None:
        """vertices: x, y, z flat (metres, the collider's frame); indices: 3 per triangle."""
        v = (ctypes.c_float * len(vertices))(*vertices)
        i = (ctypes.c_uint32 * len(indices))(*indices)
        self._check(self._lib.terrad_twin_add_mesh(self._handle(), cid, v, len(vertices) // 3, i,
                                                   len(indices) // 3, self._err))

    def remove_collider(self, cid: int) -> None:
        self._check(self._lib.terrad_twin_remove_collider(self._handle(), cid, self._err))

    def set_pose(self, cid: int, p: Sequence[float],
                 q: Sequence[float] = (1.0, 0.0, 0.0, 0.0)) -> None:
        """The pose the next tick presses at, swept from the last tick's."""
        self._check(self._lib.terrad_twin_set_pose(self._handle(), cid, *p, *q, self._err))

    def place(self, cid: int, p: Sequence[float],
              q: Sequence[float] = (1.0, 0.0, 0.0, 0.0)) -> None:
        """The collider stood here in the last tick: the next tick sweeps from this pose."""
        self._check(self._lib.terrad_twin_place(self._handle(), cid, *p, *q, self._err))

    def tick(self) -> None:
        self._check(self._lib.terrad_twin_tick(self._handle(), self._err))

    def read(self, x: int | None = None, y: int | None = None, w: int | None = None,
             h: int | None = None) -> array.array[int]:
        """A rectangle of the window (default: all of it), row-major int32 height units."""
        x, y = self.x if x is None else x, self.y if y is None else y
        w, h = self.w if w is None else w, self.h if h is None else h
        if w <= 0 or h <= 0:
            raise TwinError("read: the rectangle must be non-empty and inside the window")
        out = array.array("i", bytes(4 * w * h))
        addr, _ = out.buffer_info()
        self._check(self._lib.terrad_twin_read(self._handle(), x, y, w, h,
                                               ctypes.cast(addr, ctypes.POINTER(ctypes.c_int32)),
                                               self._err))
        return out

    def write(self, heights: Sequence[int] | Any, x: int | None = None, y: int | None = None,
              w: int | None = None, h: int | None = None) -> None:
        """The server's heights into a rectangle of the window (default: all of it)."""
        x, y = self.x if x is None else x, self.y if y is None else y
        w, h = self.w if w is None else w, self.h if h is None else h
        if w <= 0 or h <= 0:
            raise TwinError("write: the rectangle must be non-empty and inside the window")
        buf = int32s(heights, w * h, "heights")
        self._check(self._lib.terrad_twin_write(self._handle(), x, y, w, h, buf, self._err))
