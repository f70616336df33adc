// CsharpDrive.cs: the C# client (clients/csharp/Terrad.cs) against a real daemon, under Mono,
// for tests/integration/clients/test_csharp_client.py.
//
//   mono drive.exe PORT X Y W H CONFIG OUT
//
// Says hello, subscribes the window (x, y, w, h) and predicts it with CONFIG (the scene's twin
// keys), drives a sphere through it one pose batch per tick, and checks: the rut is in the
// prediction at once and arrives as DELTA frames in the mirror; CONTACT feedback came; every
// compared ACK's replay is exact; bad input (a NaN radius, an unknown model, a world name over
// 64 bytes) is refused with an exception naming the field and the client
// goes on. At the end the mirror's heights go to OUT (int32, little-endian) for the test to
// compare with GET /v1/heights. Prints "N passed, N failed"; exit 1 on a failure.
using System;
using System.IO;
using System.Threading;

static class CsharpDrive
{
    static int passed, failed;
    const int WaitMs = 120000; // generous: the machine may be loaded

    static void Check(bool ok, string what)
    {
        if (ok) {
            passed++;
        } else {
            failed++;
            Console.WriteLine("FAIL " + what);
        }
    }

    static bool Refused(Action a, string field, string what)
    {
        try {
            a();
        } catch (Terrad.TerradException e) {
            Check(e.Message.Contains(field), what + " is refused naming " + field + " (" + e.Message + ")");
            return true;
        }
        Check(false, what + " is refused");
        return false;
    }

    static bool WaitFor(Terrad.Client c, Func<bool> done)
    {
        var end = DateTime.UtcNow.AddMilliseconds(WaitMs);
        while (!done() && DateTime.UtcNow < end)
            c.Poll(20);
        return done();
    }

    static int Main(string[] args)
    {
        if (args.Length != 7) {
            Console.Error.WriteLine("usage: drive.exe PORT X Y W H CONFIG OUT");
            return 2;
        }
        int port = int.Parse(args[0]), x = int.Parse(args[1]), y = int.Parse(args[2]);
        uint w = uint.Parse(args[3]), h = uint.Parse(args[4]);
        string config = args[5], outPath = args[6];

        Refused(() => Terrad.Client.Connect("127.0.0.1", port, world: new string('w', 65),
                                            timeoutMs: WaitMs).Dispose(),
                "world", "a world name of 65 bytes");
        using (var c = Terrad.Client.Connect("127.0.0.1", port, name: "csharp-test",
                                             timeoutMs: WaitMs)) {
            Terrad.WorldInfo world = c.World;
            Check(world.Width > 0 && world.CellSizeM > 0 && world.UnitsPerM > 0,
                  "the world message: " + world.Width + "x" + world.Height);
            uint sid = c.Subscribe(x, y, w, h);
            Check(WaitFor(c, () => c.MirrorComplete(sid)), "the snapshot came");
            int[] before = c.MirrorHeights(sid);

            Refused(() => c.Predict(sid, config + " model=nope"), "model", "an unknown model");
            Terrad.Prediction p = c.Predict(sid, config);
            Refused(() => c.CreateCollider(Terrad.Shape.Sphere, radius: double.NaN), "collider_create",
                    "a NaN radius");
            uint ball = c.CreateCollider(Terrad.Shape.Sphere, radius: 0.3);

            double cell = world.CellSizeM, hz = world.TickHz;
            int row = y + (int)h / 2, n = 240;
            float z = (float)(0.4 + 0.3 - 0.06);
            double x0 = (x + 24) * cell, x1 = (x + (int)w - 24) * cell;
            bool early = false, seen = false;
            ulong deltas0 = c.Stats.DeltaFrames;
            var next = DateTime.UtcNow;
            uint seq = 0;
            for (int i = 0; i <= n; i++) {
                int k = i < n ? i : n - 1;
                var pose = new Terrad.Pose(ball, (float)(x0 + (x1 - x0) * k / (n - 1)),
                                           (float)((row + 0.5) * cell), i < n ? z : z + 5f);
                seq = c.SendPoses(new[] { pose });
                if (!seen) { // the own rut at once: in the prediction, before the server's ACK
                    int[] mine = p.Heights(), mirror = c.MirrorHeights(sid);
                    for (int j = 0; j < mine.Length && !seen; j++)
                        seen = mine[j] < mirror[j];
                    early = seen && c.Stats.AckSeq < seq;
                }
                next = next.AddSeconds(1.0 / hz);
                while (DateTime.UtcNow < next)
                    c.Poll(2);
            }
            Check(early, "the prediction shows the rut before the server's ACK of its batch");
            Check(WaitFor(c, () => (int)(c.Stats.AckSeq - seq) >= 0), "the last batch is acknowledged");
            int[] after = c.MirrorHeights(sid);
            int deepest = int.MaxValue, rowStart = (row - y) * (int)w;
            for (int j = 0; j < (int)w; j++)
                deepest = Math.Min(deepest, after[rowStart + j]);
            Check(c.Stats.DeltaFrames > deltas0 && deepest < before[rowStart] - world.UnitsPerM / 50,
                  "the rut arrived as DELTA frames (" + (c.Stats.DeltaFrames - deltas0) +
                  " frames, deepest " + deepest + " from " + before[rowStart] + ")");
            Terrad.Contact contact;
            ulong contactTick;
            Check(c.TryGetContact(ball, out contact, out contactTick) && contactTick > 0,
                  "CONTACT feedback came for the sphere (tick " + contactTick + ")");
            Terrad.PredictionStats s = p.Stats;
            Console.WriteLine("drove " + n + " ticks: " + s.Predicted + " predicted, " + s.Reconciled +
                              " reconciled, " + s.Replayed + " compared (" + s.Exact + " exact), " +
                              s.Skipped + " not compared");
            Check(s.Replayed >= 10 && s.Exact == s.Replayed,
                  "every compared ACK: the replay equals the server's heights (" + s.Exact + " of " +
                  s.Replayed + ", last differing " + s.LastDiffering + ")");
            Check(s.Errors == 0, "the twin failed on none of the prediction's events (" + s.Errors + ")");

            c.DeleteCollider(ball);
            seq = c.SendPoses(null); // an ACK after the deletion: nothing moves any more
            Check(WaitFor(c, () => (int)(c.Stats.AckSeq - seq) >= 0), "an ACK after the deletion");
            int[] final = c.MirrorHeights(sid), predicted = p.Heights();
            bool same = final.Length == predicted.Length;
            for (int j = 0; same && j < final.Length; j++)
                same = final[j] == predicted[j];
            Check(same && p.Stats.Pending == 0, "with nothing pending, the prediction is the mirror");
            using (var f = new BinaryWriter(File.Create(outPath)))
                foreach (int v in final)
                    f.Write(v);
            Check(c.Stats.Errors == 0, "no errors reached the client (" + c.LastError + ")");
        }
        Console.WriteLine(passed + " passed, " + failed + " failed");
        return failed == 0 ? 0 : 1;
    }
}
