// Terrad.cs: a C# client for terrad (proto/PROTOCOL.md) over the C library, by P/Invoke
// (docs/engines.md "C# and Unity").
//
// Why P/Invoke and not a codec of its own over System.Net.WebSockets: libterrad-client already
// holds the codec, the mirror that rebuilds a subscription from snapshots and deltas, the
// resync rules and the prediction, and the prediction must be the daemon's own deformation
// code bit for bit (libterrad-twin, which the C library loads). One implementation, tested
// against the daemon in C, Python and here; Unity loads it as a native plugin. This file uses
// only DllImport and Marshal (no System.Net, no unsafe code), so it compiles for .NET Standard
// 2.0, Mono and Unity alike; `mcs -target:library Terrad.cs` builds it with Debian's mono-mcs.
//
//     using (var c = Terrad.Client.Connect("127.0.0.1", 8081)) {
//         uint sid = c.Subscribe(0, 0, 128, 128);
//         uint ball = c.CreateCollider(Terrad.Shape.Sphere, radius: 0.3);
//         c.SendPoses(new[] { new Terrad.Pose(ball, 1f, 1f, 0.6f) });
//         while (c.Poll(20) >= 0) { int[] h = c.MirrorHeights(sid); ... }
//     }
//
// One client from one thread (as the C library): call Poll from the game's update loop.
// Failures throw TerradException with the library's sentence, which names the field.
using System;
using System.Collections.Generic;
using System.Runtime.InteropServices;
using System.Text;

namespace Terrad
{
public enum Shape { Sphere = 1, Box, Capsule, Cylinder, Wheel }

/// <summary>A collider's pose: metres, world frame; unit quaternion (w, x, y, z).</summary>
[StructLayout(LayoutKind.Sequential)]
public struct Pose
{
    public uint Id;
    public float X, Y, Z, Qw, Qx, Qy, Qz;
    public Pose(uint id, float x, float y, float z, float qw = 1, float qx = 0, float qy = 0,
                float qz = 0)
    {
        Id = id; X = x; Y = y; Z = z; Qw = qw; Qx = qx; Qy = qy; Qz = qz;
    }
}

/// <summary>The world message (terrad_world_info).</summary>
[StructLayout(LayoutKind.Sequential)]
public struct WorldInfo
{
    public int Width, Height, TileSize;
    public double CellSizeM, TickHz;
    public int UnitsPerM;
    public long HeightMin, HeightMax;
    public ulong Tick;
    public long MaxMessageBytes, MaxPosesPerBatch, MaxColliders, MaxSubscriptions;
}

/// <summary>Counters and the latest of each kind of frame (terrad_client_stats).</summary>
[StructLayout(LayoutKind.Sequential)]
public struct Stats
{
    public ulong DeltaFrames, DeltaBytes, DeltaTick, ContactFrames, ContactTick, ForcesFrames;
    public ulong Acks, AckTick;
    public uint AckSeq;
    public ulong Errors, Resyncs, Messages;
    public int LastErrorCode, CloseCode;
}

/// <summary>A collider's latest contact feedback (terrad_contact).</summary>
[StructLayout(LayoutKind.Sequential)]
public struct Contact
{
    public uint Id;
    public long Volume; // height units x cells
    public uint Cells;
    public float AreaM2, DeepestX, DeepestY, DeepestZ, NormalX, NormalY, NormalZ, SupportHeightM;
}

/// <summary>A prediction's counters (terrad_prediction_stats).</summary>
[StructLayout(LayoutKind.Sequential)]
public struct PredictionStats
{
    public ulong Predicted, Reconciled, Replayed, Exact, Skipped, OnTime, LastDiffering, Pending;
    public ulong Errors; // events the twin failed on (appended in 0.5; terrad_prediction_last_error)
}

public sealed class TerradException : Exception
{
    public readonly int Code; // a protocol error code (> 0) or a TERRAD_CLIENT_E_* (< 0)
    public TerradException(int code, string message) : base(message) { Code = code; }
}

static class Native
{
    const string Lib = "terrad-client"; // libterrad-client.so.1 (it loads libterrad-twin.so.1)

    [StructLayout(LayoutKind.Sequential)]
    internal struct Desc
    {
        public IntPtr Host;
        public int Port;
        public IntPtr Token, Name;
        public int TimeoutMs;
        public IntPtr Hook, User, Log;
        public int LogLevel, LwsLogLevels, Tls;
        public IntPtr TlsCaFile;
        public long Budget; // bytes/s (PROTOCOL.md "Budgets"); 0: the server's default, -1: none
    }

    [StructLayout(LayoutKind.Sequential)]
    internal struct ColliderDesc
    {
        public int Shape;
        public double Radius, HalfLength, Width, Hx, Hy, Hz;
        public IntPtr Material;
        public int NoFeedback;
    }

    [StructLayout(LayoutKind.Sequential)]
    internal struct Mirror
    {
        public int X, Y;
        public uint W, H, TileSize;
        public IntPtr Heights, Versions;
    }

    [DllImport(Lib)] internal static extern IntPtr terrad_client_connect_world(Desc d, IntPtr world, StringBuilder err, UIntPtr cap);
    [DllImport(Lib)] internal static extern void terrad_client_close(IntPtr c);
    [DllImport(Lib)] internal static extern IntPtr terrad_client_world(IntPtr c);
    [DllImport(Lib)] internal static extern IntPtr terrad_client_world_name(IntPtr c);
    [DllImport(Lib)] internal static extern IntPtr terrad_client_get_stats(IntPtr c);
    [DllImport(Lib)] internal static extern IntPtr terrad_client_last_error(IntPtr c);
    [DllImport(Lib)] internal static extern int terrad_client_create_collider(IntPtr c, ColliderDesc d, out uint id);
    [DllImport(Lib)] internal static extern int terrad_client_delete_collider(IntPtr c, uint id);
    [DllImport(Lib)] internal static extern int terrad_client_send_poses(IntPtr c, Pose[] poses, UIntPtr count, out uint seq);
    [DllImport(Lib)] internal static extern int terrad_client_subscribe(IntPtr c, int x, int y, uint w, uint h, out uint sid);
    [DllImport(Lib)] internal static extern int terrad_client_unsubscribe(IntPtr c, uint sid);
    [DllImport(Lib)] internal static extern IntPtr terrad_client_mirror(IntPtr c, uint sid);
    [DllImport(Lib)] internal static extern int terrad_client_mirror_complete(IntPtr c, uint sid);
    [DllImport(Lib)] internal static extern int terrad_client_contact(IntPtr c, uint collider, out Contact contact, out ulong tick);
    [DllImport(Lib)] internal static extern int terrad_client_poll(IntPtr c, int timeoutMs);
    [DllImport(Lib)] internal static extern int terrad_client_predict(IntPtr c, uint sid, IntPtr config, out IntPtr prediction);
    [DllImport(Lib)] internal static extern IntPtr terrad_prediction_heights(IntPtr p);
    [DllImport(Lib)] internal static extern IntPtr terrad_prediction_get_stats(IntPtr p);
    [DllImport(Lib)] internal static extern void terrad_prediction_stop(IntPtr p);

    /// <summary>A NUL-terminated UTF-8 copy in unmanaged memory (IntPtr.Zero for null).</summary>
    internal static IntPtr Utf8(string s)
    {
        if (s == null)
            return IntPtr.Zero;
        byte[] b = Encoding.UTF8.GetBytes(s);
        IntPtr p = Marshal.AllocHGlobal(b.Length + 1);
        Marshal.Copy(b, 0, p, b.Length);
        Marshal.WriteByte(p, b.Length, 0);
        return p;
    }

    internal static void Free(IntPtr p)
    {
        if (p != IntPtr.Zero)
            Marshal.FreeHGlobal(p);
    }

    internal static string Text(IntPtr p)
    {
        if (p == IntPtr.Zero)
            return "";
        int n = 0;
        while (Marshal.ReadByte(p, n) != 0)
            n++;
        byte[] b = new byte[n];
        Marshal.Copy(p, b, 0, n);
        return Encoding.UTF8.GetString(b);
    }
}

/// <summary>One connection to terrad (terrad_client.h).</summary>
public sealed class Client : IDisposable
{
    IntPtr c;
    readonly List<Prediction> predictions = new List<Prediction>();

    Client(IntPtr handle) { c = handle; }

    /// <summary>Connects and says hello; world null joins the default world.</summary>
    public static Client Connect(string host, int port, string token = null,
                                 string name = "terrad-cs", string world = null,
                                 int timeoutMs = 5000)
    {
        IntPtr h = Native.Utf8(host), t = Native.Utf8(token), n = Native.Utf8(name),
               w = Native.Utf8(world);
        try {
            var d = new Native.Desc { Host = h, Port = port, Token = t, Name = n,
                                      TimeoutMs = timeoutMs };
            var err = new StringBuilder(512);
            IntPtr handle = Native.terrad_client_connect_world(d, w, err, (UIntPtr)err.Capacity);
            if (handle == IntPtr.Zero)
                throw new TerradException(-12, err.ToString());
            return new Client(handle);
        } finally {
            Native.Free(h); Native.Free(t); Native.Free(n); Native.Free(w);
        }
    }

    IntPtr Handle
    {
        get {
            if (c == IntPtr.Zero)
                throw new ObjectDisposedException("Terrad.Client");
            return c;
        }
    }

    int Check(int rc)
    {
        if (rc != 0)
            throw new TerradException(rc, LastError);
        return rc;
    }

    public string LastError { get { return Native.Text(Native.terrad_client_last_error(Handle)); } }
    public WorldInfo World
    {
        get { return (WorldInfo)Marshal.PtrToStructure(Native.terrad_client_world(Handle), typeof(WorldInfo)); }
    }
    /// <summary>The world message's name ("" for a single daemon's default world).</summary>
    public string WorldName { get { return Native.Text(Native.terrad_client_world_name(Handle)); } }
    public Stats Stats
    {
        get { return (Stats)Marshal.PtrToStructure(Native.terrad_client_get_stats(Handle), typeof(Stats)); }
    }

    /// <summary>Creates a collider: sizes in metres as the shape needs (halfExtents for a box).</summary>
    public uint CreateCollider(Shape shape, double radius = 0, double halfLength = 0,
                               double width = 0, double[] halfExtents = null,
                               string material = null, bool feedback = true)
    {
        IntPtr m = Native.Utf8(material);
        try {
            var d = new Native.ColliderDesc { Shape = (int)shape, Radius = radius,
                                              HalfLength = halfLength, Width = width,
                                              Material = m, NoFeedback = feedback ? 0 : 1 };
            if (halfExtents != null && halfExtents.Length == 3) {
                d.Hx = halfExtents[0]; d.Hy = halfExtents[1]; d.Hz = halfExtents[2];
            }
            uint id;
            Check(Native.terrad_client_create_collider(Handle, d, out id));
            return id;
        } finally {
            Native.Free(m);
        }
    }

    public void DeleteCollider(uint id) { Check(Native.terrad_client_delete_collider(Handle, id)); }

    /// <summary>Sends one POSE_BATCH (an empty one asks for an ACK); its sequence number.</summary>
    public uint SendPoses(Pose[] poses)
    {
        uint seq;
        Pose[] p = poses ?? new Pose[0];
        Check(Native.terrad_client_send_poses(Handle, p, (UIntPtr)p.Length, out seq));
        return seq;
    }

    public uint Subscribe(int x, int y, uint w, uint h)
    {
        uint sid;
        Check(Native.terrad_client_subscribe(Handle, x, y, w, h, out sid));
        return sid;
    }

    public void Unsubscribe(uint sid) { Check(Native.terrad_client_unsubscribe(Handle, sid)); }

    public bool MirrorComplete(uint sid) { return Native.terrad_client_mirror_complete(Handle, sid) == 1; }

    Native.Mirror MirrorOf(uint sid)
    {
        IntPtr m = Native.terrad_client_mirror(Handle, sid);
        if (m == IntPtr.Zero)
            throw new TerradException(5, "sid: no subscription " + sid);
        return (Native.Mirror)Marshal.PtrToStructure(m, typeof(Native.Mirror));
    }

    /// <summary>A copy of the subscription's mirrored heights: w * h, row-major, height units.</summary>
    public int[] MirrorHeights(uint sid)
    {
        Native.Mirror m = MirrorOf(sid);
        var h = new int[(int)(m.W * m.H)];
        Marshal.Copy(m.Heights, h, 0, h.Length);
        return h;
    }

    /// <summary>The latest contact feedback of a collider, when any came.</summary>
    public bool TryGetContact(uint collider, out Contact contact, out ulong tick)
    {
        return Native.terrad_client_contact(Handle, collider, out contact, out tick) == 1;
    }

    /// <summary>Services the connection up to timeoutMs: messages handled, or -11 once closed.</summary>
    public int Poll(int timeoutMs) { return Native.terrad_client_poll(Handle, timeoutMs); }

    /// <summary>Predicts a subscription (docs/engines.md "Prediction"): config is the world's
    /// parameters as "key=value" pairs under the twin's keys.</summary>
    public Prediction Predict(uint sid, string config)
    {
        IntPtr cfg = Native.Utf8(config);
        try {
            IntPtr p;
            Check(Native.terrad_client_predict(Handle, sid, cfg, out p));
            Native.Mirror m = MirrorOf(sid);
            var prediction = new Prediction(p, (int)(m.W * m.H));
            predictions.Add(prediction);
            return prediction;
        } finally {
            Native.Free(cfg);
        }
    }

    public void Dispose()
    {
        if (c != IntPtr.Zero) {
            foreach (var p in predictions)
                p.Forget(); // the C library ends them with the client
            Native.terrad_client_close(c);
            c = IntPtr.Zero;
        }
    }
}

/// <summary>A predicted subscription (terrad_prediction); ends with its client or Stop().</summary>
public sealed class Prediction
{
    IntPtr p;
    readonly int cells;

    internal Prediction(IntPtr handle, int count) { p = handle; cells = count; }

    internal void Forget() { p = IntPtr.Zero; }

    IntPtr Handle
    {
        get {
            if (p == IntPtr.Zero)
                throw new ObjectDisposedException("Terrad.Prediction");
            return p;
        }
    }

    /// <summary>The predicted heights (w * h, like the mirror): the own rut at once.</summary>
    public int[] Heights()
    {
        var h = new int[cells];
        Marshal.Copy(Native.terrad_prediction_heights(Handle), h, 0, cells);
        return h;
    }

    public PredictionStats Stats
    {
        get { return (PredictionStats)Marshal.PtrToStructure(Native.terrad_prediction_get_stats(Handle), typeof(PredictionStats)); }
    }

    public void Stop()
    {
        if (p != IntPtr.Zero) {
            Native.terrad_prediction_stop(p);
            p = IntPtr.Zero;
        }
    }
}
}
