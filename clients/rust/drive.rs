// drive.rs: terrad from Rust over the C client library by FFI (docs/engines.md "Rust"): connect,
// subscribe a window, predict it, drive a sphere through it, and check that the prediction was
// exact and that the mirror holds the rut. The Go example's twin (clients/go/drive.go).
//
//     rustc --edition 2018 -O drive.rs $(pkg-config --libs-only-L terrad-client | sed 's/-L/-L native=/') \
//           -C link-arg=-Wl,-rpath,$(pkg-config --variable=libdir terrad-client)
//     ./drive PORT X Y W H "model=persson-ssbo margin_cells=4 terrain.height_m=0.4" mirror.raw
//
// No cargo and no crates: std only, so Debian's rustc (1.63) builds it offline. The structs below
// are <terrad/terrad_client.h>'s, field for field (#[repr(C)]); the two descriptors are passed by
// value, so their layout must match exactly. The last argument (optional) is where the mirror's
// heights go (int32, little-endian), for tests/integration/clients/test_rust_example.py to compare with
// GET /v1/heights. Exit status 1 when a check fails. One client from one thread, as the library asks.
use std::ffi::{CStr, CString};
use std::io::Write;
use std::os::raw::{c_char, c_double, c_float, c_int, c_void};
use std::time::{Duration, Instant};

#[repr(C)]
struct Client {
    _opaque: [u8; 0],
}
#[repr(C)]
struct Prediction {
    _opaque: [u8; 0],
}

#[repr(C)]
struct ClientDesc {
    host: *const c_char,
    port: c_int,
    token: *const c_char,
    name: *const c_char,
    timeout_ms: c_int,
    hook: Option<extern "C" fn(*mut c_void, *mut Client, c_int, u64)>,
    user: *mut c_void,
    log: Option<extern "C" fn(*mut c_void, c_int, *const c_char)>,
    log_level: c_int,
    lws_log_levels: c_int,
    tls: c_int,
    tls_ca_file: *const c_char,
    budget: i64, // bytes/s (PROTOCOL.md "Budgets"); 0: the server's default, -1: none
}

#[repr(C)]
struct WorldInfo {
    width: c_int,
    height: c_int,
    tile_size: c_int,
    cell_size_m: c_double,
    tick_hz: c_double,
    units_per_m: i32,
    height_min: i64,
    height_max: i64,
    tick: u64,
    max_message_bytes: i64,
    max_poses_per_batch: i64,
    max_colliders: i64,
    max_subscriptions: i64,
}

#[repr(C)]
struct ClientStats {
    delta_frames: u64,
    delta_bytes: u64,
    delta_tick: u64,
    contact_frames: u64,
    contact_tick: u64,
    forces_frames: u64,
    acks: u64,
    ack_tick: u64,
    ack_seq: u32,
    errors: u64,
    resyncs: u64,
    messages: u64,
    last_error_code: c_int,
    close_code: c_int,
}

const SHAPE_SPHERE: c_int = 1;

#[repr(C)]
struct ColliderDesc {
    shape: c_int,
    radius: c_double,
    half_length: c_double,
    width: c_double,
    half_extents: [c_double; 3],
    material: *const c_char,
    no_feedback: c_int,
}

#[repr(C)]
struct Pose {
    id: u32,
    x: c_float,
    y: c_float,
    z: c_float,
    qw: c_float,
    qx: c_float,
    qy: c_float,
    qz: c_float,
}

#[repr(C)]
struct Mirror {
    x: i32,
    y: i32,
    w: u32,
    h: u32,
    tile_size: u32,
    heights: *mut i32,
    versions: *mut u32,
    tx0: i64,
    ty0: i64,
    tiles_x: u32,
    tiles_y: u32,
}

#[repr(C)]
struct PredictionStats {
    predicted: u64,
    reconciled: u64,
    replayed: u64,
    exact: u64,
    skipped: u64,
    on_time: u64,
    last_differing: u64,
    pending: u64,
    errors: u64, // events the twin failed on (appended in 0.5)
}

#[link(name = "terrad-client")]
extern "C" {
    fn terrad_client_connect_world(d: ClientDesc, world: *const c_char, err: *mut c_char, cap: usize) -> *mut Client;
    fn terrad_client_close(c: *mut Client);
    fn terrad_client_world(c: *const Client) -> *const WorldInfo;
    fn terrad_client_get_stats(c: *const Client) -> *const ClientStats;
    fn terrad_client_last_error(c: *const Client) -> *const c_char;
    fn terrad_client_create_collider(c: *mut Client, d: ColliderDesc, id: *mut u32) -> c_int;
    fn terrad_client_delete_collider(c: *mut Client, id: u32) -> c_int;
    fn terrad_client_send_poses(c: *mut Client, poses: *const Pose, n: usize, seq: *mut u32) -> c_int;
    fn terrad_client_subscribe(c: *mut Client, x: i32, y: i32, w: u32, h: u32, sid: *mut u32) -> c_int;
    fn terrad_client_mirror(c: *const Client, sid: u32) -> *const Mirror;
    fn terrad_client_mirror_complete(c: *const Client, sid: u32) -> c_int;
    fn terrad_client_poll(c: *mut Client, timeout_ms: c_int) -> c_int;
    fn terrad_client_predict(c: *mut Client, sid: u32, config: *const c_char, out: *mut *mut Prediction) -> c_int;
    fn terrad_prediction_heights(p: *const Prediction) -> *const i32;
    fn terrad_prediction_get_stats(p: *const Prediction) -> *const PredictionStats;
}

fn fail(msg: String) -> ! {
    println!("FAIL {}", msg);
    std::process::exit(1);
}

fn number(s: &str) -> i32 {
    s.parse().unwrap_or_else(|_| fail(format!("{:?} is not a number", s)))
}

// The client: the C library's handle, closed when dropped.
struct Terrad(*mut Client);

impl Terrad {
    fn last_error(&self) -> String {
        unsafe { CStr::from_ptr(terrad_client_last_error(self.0)).to_string_lossy().into_owned() }
    }
    fn check(&self, rc: c_int, what: &str) {
        if rc != 0 {
            fail(format!("{}: {}", what, self.last_error()));
        }
    }
    fn poll(&self, ms: c_int) {
        unsafe { terrad_client_poll(self.0, ms) };
    }
    fn ack_seq(&self) -> u32 {
        unsafe { (*terrad_client_get_stats(self.0)).ack_seq }
    }
    fn wait_ack(&self, seq: u32) {
        let end = Instant::now() + Duration::from_secs(120);
        while (self.ack_seq().wrapping_sub(seq) as i32) < 0 {
            if Instant::now() > end {
                fail(format!("no ACK of batch {}", seq));
            }
            self.poll(20);
        }
    }
    fn send(&self, poses: &[Pose]) -> u32 {
        let mut seq = 0u32;
        self.check(unsafe { terrad_client_send_poses(self.0, poses.as_ptr(), poses.len(), &mut seq) }, "send");
        seq
    }
}

impl Drop for Terrad {
    fn drop(&mut self) {
        unsafe { terrad_client_close(self.0) };
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 7 {
        eprintln!("usage: drive PORT X Y W H CONFIG [OUT]");
        std::process::exit(2);
    }
    let (port, x, y, w, h) = (number(&args[1]), number(&args[2]), number(&args[3]), number(&args[4]), number(&args[5]));
    let name = CString::new("terrad-rust").unwrap();
    let mut err = [0 as c_char; 256];
    let desc = ClientDesc {
        host: std::ptr::null(),
        port,
        token: std::ptr::null(),
        name: name.as_ptr(),
        timeout_ms: 120000,
        hook: None,
        user: std::ptr::null_mut(),
        log: None,
        log_level: 0,
        lws_log_levels: 0,
        tls: 0,
        tls_ca_file: std::ptr::null(),
        budget: 0,
    };
    let raw = unsafe { terrad_client_connect_world(desc, std::ptr::null(), err.as_mut_ptr(), err.len()) };
    if raw.is_null() {
        fail(format!("connect: {}", unsafe { CStr::from_ptr(err.as_ptr()) }.to_string_lossy()));
    }
    let c = Terrad(raw);
    let world = unsafe { &*terrad_client_world(c.0) };

    let mut sid = 0u32;
    c.check(unsafe { terrad_client_subscribe(c.0, x, y, w as u32, h as u32, &mut sid) }, "subscribe");
    let end = Instant::now() + Duration::from_secs(120);
    while unsafe { terrad_client_mirror_complete(c.0, sid) } == 0 {
        if Instant::now() > end {
            fail("no snapshot".to_string());
        }
        c.poll(20);
    }
    let mut pred: *mut Prediction = std::ptr::null_mut();
    let bad = CString::new(format!("{} model=nope", args[6])).unwrap();
    if unsafe { terrad_client_predict(c.0, sid, bad.as_ptr(), &mut pred) } == 0 {
        fail("an unknown model was taken".to_string());
    }
    println!("refused as it should be: {}", c.last_error());
    let config = CString::new(args[6].as_str()).unwrap_or_else(|_| fail("CONFIG holds a NUL byte".to_string()));
    c.check(unsafe { terrad_client_predict(c.0, sid, config.as_ptr(), &mut pred) }, "predict");
    let sphere = ColliderDesc {
        shape: SHAPE_SPHERE,
        radius: 0.3,
        half_length: 0.0,
        width: 0.0,
        half_extents: [0.0; 3],
        material: std::ptr::null(),
        no_feedback: 0,
    };
    let mut ball = 0u32;
    c.check(unsafe { terrad_client_create_collider(c.0, sphere, &mut ball) }, "collider");

    // One pose batch a tick, along x through the window with a 24-cell halo at both ends.
    let (cell, hz) = (world.cell_size_m, world.tick_hz);
    let (x0, x1) = ((x + 24) as f64 * cell, (x + w - 24) as f64 * cell);
    let row = y + h / 2;
    let n = 240;
    let mut seq = 0u32;
    let mut next = Instant::now();
    for i in 0..=n {
        let (k, z) = if i == n { (n - 1, 0.4 + 0.3 - 0.06 + 5.0) } else { (i, 0.4 + 0.3 - 0.06) }; // the last: lifted
        let px = x0 + (x1 - x0) * k as f64 / (n - 1) as f64;
        let py = (row as f64 + 0.5) * cell;
        seq = c.send(&[Pose { id: ball, x: px as f32, y: py as f32, z: z as f32, qw: 1.0, qx: 0.0, qy: 0.0, qz: 0.0 }]);
        next += Duration::from_secs_f64(1.0 / hz);
        while Instant::now() < next {
            c.poll(2);
        }
    }
    // A predicted collider leaves the prediction when it is deleted: delete it once its last
    // batch is acknowledged, or the replay of that batch's tick misses it.
    c.wait_ack(seq);
    c.check(unsafe { terrad_client_delete_collider(c.0, ball) }, "delete");
    c.wait_ack(c.send(&[])); // an ACK after the deletion

    let s = unsafe { &*terrad_client_get_stats(c.0) };
    let ps = unsafe { &*terrad_prediction_get_stats(pred) };
    let cells = (w * h) as usize;
    let m = unsafe { &*terrad_client_mirror(c.0, sid) };
    let mirror = unsafe { std::slice::from_raw_parts(m.heights as *const i32, cells) };
    let predicted = unsafe { std::slice::from_raw_parts(terrad_prediction_heights(pred), cells) };
    let strip = &mirror[((row - y) * w) as usize..((row - y + 1) * w) as usize];
    let (top, deepest) = (strip[0], *strip.iter().min().unwrap());
    println!(
        "drove {} ticks: {} DELTA frames, {} ACKs; prediction: {} compared, {} exact; rut {} units deep",
        n, s.delta_frames, s.acks, ps.replayed, ps.exact, top - deepest
    );
    if ps.replayed < 10 || ps.exact != ps.replayed {
        fail(format!("the prediction was not exact at every compared ACK ({} of {})", ps.exact, ps.replayed));
    }
    if ps.errors != 0 {
        fail(format!("the twin failed on {} of the prediction's events", ps.errors));
    }
    if mirror != predicted || top - deepest < world.units_per_m / 50 {
        fail("the mirror holds no rut, or the prediction differs from it".to_string());
    }
    if let Some(out) = args.get(7) {
        let bytes: Vec<u8> = mirror.iter().flat_map(|v| v.to_le_bytes()).collect();
        let mut f = std::fs::File::create(out).unwrap_or_else(|e| fail(format!("{}: {}", out, e)));
        f.write_all(&bytes).unwrap_or_else(|e| fail(format!("{}: {}", out, e)));
    }
    println!("ok");
}
