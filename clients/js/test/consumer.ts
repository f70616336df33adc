// A TypeScript application of terrad-client, type-checked (tsc --noEmit) against the installed
// package's declarations by tests/integration/clients/test_ts_client.sh: the types are there and bite.
import { TerradClient, TerradError, Worlds, type Pose } from 'terrad-client';

export async function drive(url: string, http: string): Promise<bigint> {
  const c = await TerradClient.connect(url, { name: 'typed' });
  const sid: number = await c.subscribe(0, 0, 32, 32);
  const mirror = await c.waitComplete(sid);
  const h: Int32Array = mirror.heights;
  const worlds = new Worlds(http);
  await c.predict(sid, await worlds.twinConfig(), await worlds.twinWasm());
  const id: number = await c.createCollider('wheel', { radius: 0.3, width: 0.2 });
  const pose: Pose = { id, x: 1, y: 1, z: 0.5 + h[0] / c.world.units_per_m, qw: 1, qx: 0, qy: 0, qz: 0 };
  c.on('error', (e: TerradError) => console.log(e.field));
  // @ts-expect-error a pose needs its quaternion
  c.sendPoses([{ id, x: 1, y: 1, z: 0.5 }]);
  // @ts-expect-error no such shape
  await c.createCollider('cone', { radius: 1 });
  return c.waitAck(c.sendPoses([pose]));
}

// A late joiner with base snapshots: the world says whether the server agreed; the mirror's base.
export async function join(url: string, http: string): Promise<number> {
  const c = await TerradClient.connect(url, { baseSnapshots: true, twinWasm: await new Worlds(http).twinWasm() });
  const agreed: boolean | undefined = c.world.snapshot_base;
  const mirror = await c.waitComplete(await c.subscribe(0, 0, 32, 32));
  const base: Int32Array | null = mirror.base;
  // @ts-expect-error baseSnapshots is a boolean; the twin's bytes go in twinWasm
  await TerradClient.connect(url, { baseSnapshots: new Uint8Array() });
  return agreed && base ? mirror.heights[0] - base[0] : 0;
}
