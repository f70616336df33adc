"""terrad: the Python client of the terrad terrain deformation service.

    import asyncio, terrad

    async def main():
        async with terrad.Client("ws://127.0.0.1:8081/") as client:
            wheel = await client.create_collider("wheel", radius=0.3, width=0.2)
            sid = await client.subscribe(0, 0, 128, 128)
            await client.wait_complete(sid)
            seq = await client.send_poses([terrad.Pose(wheel, 1.0, 1.0, 0.5)])
            await client.wait_ack(seq)
            print(client.heights(sid))   # NumPy int32 (h, w) when NumPy is there

    asyncio.run(main())

Modules: terrad.proto (the wire codecs: proto/PROTOCOL.md), terrad.client (the asyncio
Client), terrad.sync (SyncClient, the same without asyncio), terrad.http (the HTTP API),
terrad.twin (the twin library, libterrad-twin, through ctypes) and terrad.predict
(Client.predict: the own rut at once, reconciled with the server at every ACK) and
terrad.vecenv (WheelVecEnv: K client-clocked worlds stepped as one, reset()/step(actions)).
Everything public is also here at the top level.
"""

from . import proto
from .client import CALLBACK_ARGS, HAVE_NUMPY, Client, TerradClient, heights_grid
from .proto import *  # noqa: F401,F403 - the codec's public names
from .proto import __all__ as _proto_all
from .predict import Prediction
from .sync import SyncClient
from .twin import Twin, TwinError
from .http import (WorldError, create_world, delete_world, get_heights, get_stats, get_world,
                   list_worlds)
from .vecenv import OBS_FIELDS, WheelVecEnv, wheel_scene

__version__ = "0.3.0"

__all__ = ["CALLBACK_ARGS", "HAVE_NUMPY", "Client", "Prediction", "SyncClient", "TerradClient",
           "Twin", "TwinError", "WorldError", "create_world", "delete_world", "get_heights",
           "get_stats", "get_world", "heights_grid", "list_worlds", "proto", "OBS_FIELDS",
           "WheelVecEnv", "wheel_scene", *_proto_all]
