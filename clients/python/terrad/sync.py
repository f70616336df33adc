"""A small synchronous facade over terrad.Client, for scripts and simulators that do not use
asyncio: the client runs on its own event loop in a background thread, and each method blocks
until its coroutine is done there.

    with SyncClient("ws://127.0.0.1:8081/") as client:
        wheel = client.create_collider("wheel", radius=0.3, width=0.2)
        sid = client.subscribe(0, 0, 128, 128)
        client.wait_complete(sid)
        seq = client.send_poses([Pose(wheel, 1.0, 1.0, 0.5)])
        client.wait_ack(seq)
        heights = client.heights(sid)

Callbacks added with on() run on the background thread.
"""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable, Coroutine
from typing import Any, TypeVar

from .client import Callback, Client, FrameKind
from .proto import Contact, Pose

T = TypeVar("T")


class BackgroundLoop:
    """A private asyncio loop on a daemon thread, and blocking calls onto it (SyncClient,
    terrad.vecenv.WheelVecEnv). Subclasses set .timeout and define close()."""

    timeout: float = 10.0

    def _start_loop(self, name: str) -> None:
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name=name, daemon=True)
        self._thread.start()

    def _call(self, coro: Coroutine[Any, Any, T], timeout: float | None = None) -> T:
        fut = asyncio.run_coroutine_threadsafe(coro, self._loop)
        return fut.result(self.timeout + 5 if timeout is None else timeout)

    def _stop_loop(self) -> None:
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(10)
        self._loop.close()

    def close(self) -> None:
        raise NotImplementedError

    def __enter__(self):
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class SyncClient(BackgroundLoop):
    """Blocking calls onto a Client (the attribute .client) that lives on a private loop."""

    def __init__(self, uri: str, token: str = "", name: str = "terrad-python-sync",
                 timeout: float = 10.0, **connect_kwargs: Any):
        self.timeout = timeout
        self._start_loop("terrad-client")
        self.client = Client(uri, token=token, name=name, **connect_kwargs)
        try:
            self._call(self.client.connect())
        except BaseException:
            self._stop_loop()
            raise

    def close(self) -> None:
        if self._loop.is_closed():
            return
        try:
            self._call(self.client.close())
        finally:
            self._stop_loop()

    @property
    def world(self) -> dict[str, Any]:
        return self.client.world

    def on(self, kind: FrameKind, callback: Callback) -> Callback:
        """As Client.on; the callback runs on the client's background thread."""
        return self.client.on(kind, callback)

    def create_collider(self, shape: str, material: str = "default", **dims: Any) -> int:
        return self._call(self.client.create_collider(shape, material, **dims))

    def delete_collider(self, cid: int) -> None:
        self._call(self.client.delete_collider(cid))

    def send_poses(self, poses: list[Pose]) -> int:
        return self._call(self.client.send_poses(poses))

    def step(self, ticks: int = 1, sets: list[list[Pose]] | None = None,
             timeout: float | None = None) -> int:
        """A client-clocked world's STEP (Client.step): its last tick, once it is durable."""
        t = self.timeout if timeout is None else timeout
        return self._call(self.client.step(ticks, sets, t), t + 5)

    def edit(self, op: str, **fields: Any) -> dict[str, Any]:
        """A terrain edit; the server's "edited" reply (Client.edit)."""
        return self._call(self.client.edit(op, **fields))

    def subscribe(self, x: int, y: int, w: int, h: int, colliders: bool = False,
                  footprints: bool = False, grousers: bool = False) -> int:
        return self._call(self.client.subscribe(x, y, w, h, colliders, footprints, grousers))

    def unsubscribe(self, sid: int) -> None:
        self._call(self.client.unsubscribe(sid))

    def wait_ack(self, seq: int, timeout: float | None = None) -> None:
        t = self.timeout if timeout is None else timeout
        self._call(self.client.wait_ack(seq, t), t + 5)

    def wait_complete(self, sid: int, timeout: float | None = None) -> None:
        t = self.timeout if timeout is None else timeout
        self._call(self.client.wait_complete(sid, t), t + 5)

    def wait_for(self, predicate: Callable[[], bool], timeout: float | None = None) -> None:
        """predicate runs on the background thread, after every message."""
        t = self.timeout if timeout is None else timeout
        self._call(self.client.wait_for(predicate, t), t + 5)

    def heights(self, sid: int) -> Any:
        """As Client.heights (a copy taken on the client's thread)."""
        async def copy() -> Any:
            return self.client.heights(sid)
        return self._call(copy())

    def contact(self, cid: int) -> Contact | None:
        """The latest contact feedback of collider cid, or None."""
        async def get() -> Contact | None:
            return self.client.contacts.get(cid)
        return self._call(get())

    @property
    def acked_tick(self) -> int:
        return self.client.acked_tick
