"""terrad.vecenv: K client-clocked worlds stepped as one, the way reinforcement-learning trainers
step vectorised environments (issue 30; PROTOCOL.md "STEP").

    env = WheelVecEnv("http://127.0.0.1:8080", "ws://127.0.0.1:8081/", num_envs=8)
    obs, info = env.reset(seed=0)
    while True:
        obs, reward, terminated, truncated, info = env.step(np.full(8, 0.2, np.float32))
        if (terminated | truncated).all():
            break
    env.close()

The interface is the common RL one by convention — Gymnasium's VectorEnv shape: reset() ->
(observations, info), step(actions) -> (observations, rewards, terminated, truncated, info),
every value a NumPy array batched over the K environments — without importing any RL package
(none is in the registries this project uses). Unlike Gymnasium's vector environments there is
no automatic reset: an environment that ended keeps reporting terminated or truncated (its wheel
holds) until the next reset(), which starts all K afresh.

Each environment is its own world on the daemon (created by reset() with "clock": "client",
deleted by close()), so its soil starts untouched every episode and its ticks run beside the
others' on the daemon's shared pool of sim workers: one step() sends all K STEPs before it waits
for any STEPPED. The task: a rigid wheel on the scene's soil, load-driven (its height is the
soil's, carrying load_n), moving along x at speed_m_s; the action is each wheel's slip ratio in
[-0.9, 0.9] (its spin from the speed); the observation its FORCES entry of the step's last tick
and where it is; the reward its drawbar pull coefficient (pull / load). Deterministic: the same
seed (unused: the task has no randomness) and actions give the same arrays bit for bit, whether
the K worlds are stepped as one or each alone (test_cosim_python).
"""

from __future__ import annotations

import asyncio
import math
from typing import Any

from .client import Client
from .http import WorldError, create_world, delete_world
from .proto import Pose
from .sync import BackgroundLoop

try:
    import numpy as np
except ImportError:  # pragma: no cover - the environment needs NumPy
    np = None  # type: ignore[assignment]

#: observation columns
OBS_FIELDS = ("force_x_n", "force_z_n", "torque_y_nm", "sinkage_m", "slip", "x_m")


def wheel_scene(width: int = 160, height: int = 24, cell_size_m: float = 0.02,
                ground_m: float = 0.3, soil: str = "ding2011") -> dict[str, Any]:
    """A flat client-clocked bin of bekker soil (a preset name) for one wheel."""
    return {"name": "wheel-bin", "clock": "client",
            "world": {"width": width, "height": height, "cell_size_m": cell_size_m},
            "terrain": {"kind": "flat", "height_m": ground_m},
            "material": {"model": "bekker", "compression": 0.5, "soil": {"preset": soil}}}


class _Env:
    """One world's driver (on the vector environment's loop)."""

    def __init__(self, name: str):
        self.name = name
        self.client: Client | None = None
        self.wheel = 0
        self.x = self.angle = 0.0
        self.ended = False


class WheelVecEnv(BackgroundLoop):
    """K worlds, one driven wheel each, stepped as one. Arrays: observations float32 (K, 6)
    (OBS_FIELDS), rewards float32 (K,), terminated and truncated bool (K,), info {"tick": int64
    (K,)}."""

    def __init__(self, http: str, ws: str, num_envs: int, scene: dict[str, Any] | None = None,
                 prefix: str = "vecenv", radius_m: float = 0.15, width_m: float = 0.1,
                 load_n: float = 60.0, speed_m_s: float = 0.3, ticks_per_step: int = 1,
                 max_steps: int = 200, token: str = "", timeout: float = 60.0):
        if np is None:
            raise ImportError("terrad.vecenv needs NumPy")
        self.http, self.ws, self.num_envs, self.token = http, ws, num_envs, token
        self.scene = scene or wheel_scene()
        self.radius, self.width, self.load_n = radius_m, width_m, load_n
        self.speed, self.ticks_per_step, self.max_steps = speed_m_s, ticks_per_step, max_steps
        self.timeout = timeout
        self.envs = [_Env(f"{prefix}-{i}") for i in range(num_envs)]
        self.steps = 0
        w = self.scene["world"]
        self.cell = w["cell_size_m"]
        self.x0, self.x_end = 4 * radius_m, w["width"] * self.cell - 4 * radius_m
        self.y = w["height"] * self.cell / 2
        self.z = self.scene["terrain"]["height_m"] + radius_m
        self.dt = 1.0 / float(self.scene.get("tick_hz", 60))
        self._start_loop("terrad-vecenv")

    # ---- the Gymnasium-shaped calls (blocking) ------------------------------------------------

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None):
        """Every world made afresh (deleted and created), a wheel placed in each and one tick
        run: (observations, info)."""
        del seed, options  # the task has no randomness
        return self._call(self._reset(), self.timeout + 30)

    def step(self, actions):
        """actions: K slip ratios. One STEP per world, all sent before any is awaited."""
        a = np.clip(np.asarray(actions, dtype=np.float64).reshape(self.num_envs), -0.9, 0.9)
        return self._call(self._step(a), self.timeout + 30)

    def close(self) -> None:
        """The worlds deleted, the connections closed, the loop stopped."""
        if self._loop.is_closed():
            return
        try:
            self._call(self._close(), self.timeout + 30)
        finally:
            self._stop_loop()

    # ---- on the loop --------------------------------------------------------------------------

    async def _drop(self, e: _Env) -> None:
        if e.client is not None:
            await e.client.close()
            e.client = None
        try:
            await asyncio.to_thread(delete_world, self.http, e.name, False, self.token)
        except WorldError as err:
            if err.status != 404:
                raise

    async def _open(self, e: _Env) -> None:
        await self._drop(e)
        await asyncio.to_thread(create_world, self.http, e.name, self.scene, None, self.token)
        e.client = Client(self.ws, token=self.token, name="terrad-vecenv", world=e.name)
        await e.client.connect()
        e.wheel = await e.client.create_collider("wheel", radius=self.radius, width=self.width,
                                                 load_n=self.load_n)
        e.x, e.angle, e.ended = self.x0, 0.0, False

    async def _reset(self):
        await asyncio.gather(*(self._open(e) for e in self.envs))
        self.steps = 0
        return await self._run(np.zeros(self.num_envs), first=True)

    async def _step(self, slips):
        return await self._run(slips, first=False)

    def _poses(self, e: _Env, slip: float, ticks: int) -> list[list[Pose]]:
        """The wheel's pose at each of the step's ticks: along x at the speed, spinning as the
        slip says (driving: v = wR(1 - s))."""
        omega = self.speed / (self.radius * (1.0 - slip))
        sets = []
        for _ in range(ticks):
            sets.append([Pose(e.wheel, e.x, self.y, self.z, math.cos(e.angle / 2), 0.0,
                              math.sin(e.angle / 2), 0.0)])
            e.x += self.speed * self.dt
            e.angle += omega * self.dt
        return sets

    async def _run(self, slips, first: bool):
        ticks = 1 if first else self.ticks_per_step
        futs = []
        for e, s in zip(self.envs, slips):
            if e.ended:  # holds until reset
                futs.append(await e.client.step_send(ticks))
            else:
                futs.append(await e.client.step_send(ticks, self._poses(e, float(s), ticks)))
        tick = np.array(await asyncio.wait_for(asyncio.gather(*futs), self.timeout), np.int64)
        if not first:
            self.steps += 1
        obs = np.zeros((self.num_envs, len(OBS_FIELDS)), np.float32)
        for i, e in enumerate(self.envs):
            f = e.client.forces.get(e.wheel)
            if f is not None and e.client.forces_tick == tick[i]:
                obs[i, :5] = (f.force[0], f.force[2], f.torque[1], f.sinkage_m, f.slip)
            obs[i, 5] = e.x
        terminated = np.array([e.x >= self.x_end for e in self.envs])
        truncated = np.full(self.num_envs, self.steps >= self.max_steps) & ~terminated
        for e, t, u in zip(self.envs, terminated, truncated):
            e.ended = e.ended or bool(t) or bool(u)
        info = {"tick": tick}
        if first:
            return obs, info
        reward = (obs[:, 0] / np.float32(self.load_n)).astype(np.float32)
        return obs, reward, terminated, truncated, info

    async def _close(self) -> None:
        await asyncio.gather(*(self._drop(e) for e in self.envs), return_exceptions=True)
