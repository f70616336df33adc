/*
 * mujoco_rover.c: a real physics engine as terrad's client (docs/simulators.md). A four-wheeled
 * rover whose body, suspension and motors are MuJoCo's (mujoco_rover.xml, loaded by mj_loadXML)
 * and whose wheel-ground contact is terrad's soil, in lockstep with a client-clocked world:
 *
 *     every step k (dt = the world's tick, 1 / tick_hz):
 *       mj_step1            MuJoCo's kinematics at q_k: each wheel body's xpos, xquat
 *       STEP (1 tick)       those four poses go to terrad; the tick deforms the soil under the
 *                           wheels and answers their FORCES (force and torque, world frame)
 *       xfrc_applied        the FORCES on the wheel bodies; the motors' torque into ctrl
 *       mj_step2            MuJoCo integrates to q_k+1
 *
 * Explicit coupling: the soil's force at q_k acts over the whole step. It is stable while dt is
 * well under the soil contact's period, dt < 2 sqrt(m_wheel / (E A)) with E the soil's
 * elastic_pa_m and A the contact area (docs/simulators.md, "Stability": measured bound and
 * remedy). Nothing here reads a clock: the same model, scene and steps give the same bits on
 * every run (the digest printed at the end hashes every step's state and forces).
 *
 *     mujoco_rover --write-scene snow-us DIR [--slip-n 0.4] [--hz 500]   the ramp world's scene
 *     terrad serve --scene DIR/rover-snow-us.json --no-demo
 *     mujoco_rover [--host H] [--port 8081] [--token T] [--model mujoco_rover.xml]
 *
 * The world: 7 m x 1.2 m of 2.5 cm cells, flat ground 0.5 m high, a 20-degree ramp from
 * x = 1.5 m rising 1 m, flat again at the top. The rover starts on the ramp (its rear wheels
 * 0.3 m up it), pitched with it and its wheels touching the slope, and drives for at most
 * --seconds (default 14) of simulated time. Prints a line a
 * simulated second and a verdict: "climbed" (the rear wheels past the top), "bogged" (moved
 * < 5 cm in the last 3 s, the wheels spinning: mean slip > 0.5) or "neither"; exits 0 when the
 * run completed, whatever the verdict (the test judges it), 1 on a failure, 2 on bad arguments.
 *
 * Build: cmake builds it when MuJoCo is found (Debian: libmujoco-dev, scripts/deps), or
 *     cc mujoco_rover.c -o mujoco_rover $(pkg-config --cflags --libs terrad-client) -lmujoco -lm
 */
#define _POSIX_C_SOURCE 200809L

#include <errno.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include <mujoco/mujoco.h>
#include <terrad/terrad_client.h>

/* ---- The world (its scene is written by --write-scene; every number here is the scene's) ---- */

#define PI 3.14159265358979323846 /* M_PI is not C11's */

#define CELL_M 0.025
#define WORLD_W 280 /* cells: 7 m along the ramp */
#define WORLD_H 48  /* 1.2 m across */
#define UNITS_PER_M 10000
#define GROUND_M 0.5
#define RAMP_X_M 1.5
#define SLOPE_DEG 20.0
#define RISE_M 1.0

/* ---- The rover (mujoco_rover.xml holds the rest) ---- */

#define WHEELS 4
#define WHEEL_RADIUS_M 0.2
#define WHEEL_WIDTH_M 0.12
#define HALF_BASE_M 0.35 /* wheel x from the chassis centre */
#define AXLE_DROP_M 0.15 /* the axles below the chassis centre */
#define START_S_M 0.65   /* the chassis starts this far up the ramp: rear wheels 0.3 m up */
#define MOTOR_STALL_NM 40.0
#define MOTOR_FREE_RAD_S 5.0 /* 1 m/s at no slip */

static const char *const wheel_names[WHEELS] = {"fl", "fr", "rl", "rr"};

typedef struct rover {
    mjModel *m;
    mjData *d;
    int chassis;            /* body */
    int wheel[WHEELS];      /* bodies */
    int axle_dof[WHEELS];   /* each axle hinge's dof (qvel index) */
    int motor[WHEELS];      /* actuators */
    uint32_t ids[WHEELS];   /* terrad's wheel colliders */
    terrad_force f[WHEELS]; /* the last tick's FORCES */
    uint64_t digest;        /* FNV-1a over every step's state and forces */
} rover;

static double surface_m(double x)
{
    double up = (x - RAMP_X_M) * tan(SLOPE_DEG * PI / 180.0);
    return GROUND_M + fmin(fmax(up, 0.0), RISE_M);
}

/* the chassis' x at which its rear wheels are over the top of the ramp */
static double top_x_m(void)
{
    return RAMP_X_M + RISE_M / tan(SLOPE_DEG * PI / 180.0) + HALF_BASE_M;
}

/* ---- --write-scene: the world's heights and its scene file ---- */

static int write_scene(const char *soil, double slip_n, double hz, const char *dir)
{
    char path[4096];
    snprintf(path, sizeof path, "%s/ramp.i32", dir);
    FILE *f = fopen(path, "wb");
    if (!f) {
        fprintf(stderr, "mujoco_rover: %s: %s\n", path, strerror(errno));
        return 1;
    }
    /* every row: the ground at each cell's centre, little-endian int32 height units */
    int ok = 1;
    for (int y = 0; y < WORLD_H; y++)
        for (int x = 0; x < WORLD_W; x++) {
            int32_t h = (int32_t)lround(surface_m((x + 0.5) * CELL_M) * UNITS_PER_M);
            uint8_t le[4] = {(uint8_t)h, (uint8_t)(h >> 8), (uint8_t)(h >> 16), (uint8_t)(h >> 24)};
            ok &= fwrite(le, 1, 4, f) == 4;
        }
    ok &= fclose(f) == 0;
    snprintf(path, sizeof path, "%s/rover-%s.json", dir, soil);
    FILE *s = ok ? fopen(path, "w") : NULL;
    if (!s) {
        fprintf(stderr, "mujoco_rover: cannot write %s\n", path);
        return 1;
    }
    fprintf(s,
            "{\"name\": \"rover-%s\", \"clock\": \"client\", \"tick_hz\": %.17g,\n"
            " \"world\": {\"width\": %d, \"height\": %d, \"cell_size_m\": %g, "
            "\"units_per_m\": %d},\n"
            " \"terrain\": {\"kind\": \"raw_int32\", \"path\": \"ramp.i32\"},\n"
            " \"material\": {\"model\": \"bekker\", \"compression\": 0.5,\n"
            "              \"soil\": {\"preset\": \"%s\", \"slip_n\": %g}}}\n",
            soil, hz, WORLD_W, WORLD_H, CELL_M, UNITS_PER_M, soil, slip_n);
    if (fclose(s) != 0) {
        fprintf(stderr, "mujoco_rover: cannot write %s\n", path);
        return 1;
    }
    printf("%s\n", path);
    return 0;
}

/* ---- MuJoCo's side ---- */

static int named(const mjModel *m, int type, const char *prefix, const char *wheel, char *err,
                 size_t cap)
{
    char name[64];
    snprintf(name, sizeof name, "%s%s", prefix, wheel);
    int id = mj_name2id(m, type, name);
    if (id < 0)
        snprintf(err, cap, "the model has no \"%s\"", name);
    return id;
}

/* The model with its timestep set to the world's tick. */
static int rover_load(rover *r, const char *path, double dt, char *err, size_t cap)
{
    memset(r, 0, sizeof *r);
    r->m = mj_loadXML(path, NULL, err, (int)cap);
    if (!r->m)
        return -1;
    r->m->opt.timestep = dt;
    r->chassis = named(r->m, mjOBJ_BODY, "chassis", "", err, cap);
    for (int i = 0; i < WHEELS; i++) {
        r->wheel[i] = named(r->m, mjOBJ_BODY, "wheel_", wheel_names[i], err, cap);
        int axle = named(r->m, mjOBJ_JOINT, "axle_", wheel_names[i], err, cap);
        r->motor[i] = named(r->m, mjOBJ_ACTUATOR, "motor_", wheel_names[i], err, cap);
        if (r->wheel[i] < 0 || axle < 0 || r->motor[i] < 0 || r->chassis < 0)
            return -1;
        r->axle_dof[i] = r->m->jnt_dofadr[axle];
    }
    r->d = mj_makeData(r->m);
    r->digest = 0xcbf29ce484222325ull;
    if (!r->d) {
        snprintf(err, cap, "mj_makeData: out of memory");
        return -1;
    }
    return 0;
}

static void rover_free(rover *r)
{
    if (r->d)
        mj_deleteData(r->d);
    if (r->m)
        mj_deleteModel(r->m);
}

/* The chassis on the ramp, START_S_M up it and pitched with it, each wheel touching the
 * undeformed slope (its centre a radius from the slope's plane): the free joint's qpos. */
static void rover_place(rover *r)
{
    double th = SLOPE_DEG * PI / 180.0, h = WHEEL_RADIUS_M + AXLE_DROP_M;
    mjtNum *q = r->d->qpos + r->m->jnt_qposadr[r->m->body_jntadr[r->chassis]];
    q[0] = RAMP_X_M + START_S_M * cos(th) - h * sin(th);
    q[2] = GROUND_M + START_S_M * sin(th) + h * cos(th);
    /* nose up: a turn of -th about y */
    q[3] = cos(th / 2);
    q[4] = 0;
    q[5] = -sin(th / 2);
    q[6] = 0;
}

static void hash(rover *r, const void *data, size_t n)
{
    const uint8_t *p = data;
    for (size_t i = 0; i < n; i++)
        r->digest = (r->digest ^ p[i]) * 0x100000001b3ull;
}

/* The wheels' poses at q_k (after mj_step1): a wheel body's frame is terrad's wheel collider
 * frame (the axle its y), so xpos and xquat go as they are. */
static void rover_poses(const rover *r, terrad_pose out[WHEELS])
{
    for (int i = 0; i < WHEELS; i++) {
        const mjtNum *p = r->d->xpos + 3 * r->wheel[i], *q = r->d->xquat + 4 * r->wheel[i];
        out[i] = (terrad_pose){r->ids[i],   (float)p[0], (float)p[1], (float)p[2],
                               (float)q[0], (float)q[1], (float)q[2], (float)q[3]};
    }
}

/* The tick's FORCES on the wheel bodies (at their centres of mass: the pose positions), the
 * motors' torque falling linearly from stall to zero at the free speed. */
static void rover_apply(rover *r)
{
    mju_zero(r->d->xfrc_applied, 6 * r->m->nbody);
    for (int i = 0; i < WHEELS; i++) {
        mjtNum *x = r->d->xfrc_applied + 6 * r->wheel[i];
        for (int k = 0; k < 3; k++) {
            x[k] = r->f[i].force[k];
            x[3 + k] = r->f[i].torque[k];
        }
        double omega = r->d->qvel[r->axle_dof[i]];
        r->d->ctrl[r->motor[i]] =
            MOTOR_STALL_NM * fmin(1.0, fmax(0.0, 1.0 - omega / MOTOR_FREE_RAD_S));
    }
    hash(r, r->f, sizeof r->f);
}

/* ---- The run ---- */

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + ts.tv_nsec / 1e9;
}

/* One step of both engines: 0, or the client's error. */
static int step(rover *r, terrad_client *c)
{
    terrad_pose poses[WHEELS];
    mj_step1(r->m, r->d);
    rover_poses(r, poses);
    terrad_step s = {.ticks = 1, .poses = poses, .count = WHEELS, .sets = 1};
    uint64_t tick;
    int rc = terrad_client_step(c, &s, &tick);
    if (rc != 0)
        return rc;
    /* this tick's entry; none (a wheel the tick held back) pushes nothing */
    for (int i = 0; i < WHEELS; i++) {
        uint64_t at = 0;
        if (!terrad_client_force(c, r->ids[i], &r->f[i], &at) || at != tick)
            memset(&r->f[i], 0, sizeof r->f[i]);
    }
    rover_apply(r);
    mj_step2(r->m, r->d);
    hash(r, r->d->qpos, sizeof(mjtNum) * (size_t)r->m->nq);
    hash(r, r->d->qvel, sizeof(mjtNum) * (size_t)r->m->nv);
    return 0;
}

typedef struct args {
    const char *host, *token, *world, *model;
    int port;
    double seconds;
} args;

/* Per step: the chassis' x, the wheels' mean slip and sinkage. */
typedef struct track {
    double *x, *slip, *sink;
    long n;
    double x0;      /* where the chassis started */
    double chatter; /* sum over steps and wheels of (Fz_k - Fz_k-1)^2 */
} track;

/* Mean of v over steps [from, to). */
static double mean(const double *v, long from, long to)
{
    double s = 0;
    for (long i = from; i < to; i++)
        s += v[i];
    return to > from ? s / (double)(to - from) : 0.0;
}

static void verdict(const rover *r, const track *t, double dt, double wall_s)
{
    long second = (long)llround(1.0 / dt), last3 = 3 * second, n = t->n;
    double x = n ? t->x[n - 1] : t->x0, top = top_x_m();
    int climbed = x > top;
    int stalled = n > last3 && t->x[n - 1] - t->x[n - 1 - last3] < 0.05;
    double slip3 = mean(t->slip, n > last3 ? n - last3 : 0, n);
    const char *v = climbed ? "climbed" : stalled && slip3 > 0.5 ? "bogged" : "neither";
    printf("%s: moved %.3f m (the top is %.3f m away), slip %.3f, sinkage %.1f mm (second 2: "
           "%.1f mm), Fz chatter %.1f N, %ld steps of %g ms, digest %016llx\n",
           v, x - t->x0, top - x, slip3, 1e3 * mean(t->sink, n > second ? n - second : 0, n),
           1e3 * mean(t->sink, second < n ? second : n, 2 * second < n ? 2 * second : n),
           n ? sqrt(t->chatter / (WHEELS * (double)n)) : 0.0, n, 1e3 * dt,
           (unsigned long long)r->digest);
    printf("speed: %ld steps in %.2f s of wall time, %.1f x real time\n", n, wall_s,
           wall_s > 0 ? n * dt / wall_s : 0.0);
}

static int drive(const args *a)
{
    char err[512];
    terrad_client_desc desc = {.host = a->host,
                               .port = a->port,
                               .token = a->token,
                               .name = "mujoco-rover",
                               .timeout_ms = 120000};
    terrad_client *c = terrad_client_connect_world(desc, a->world, err, sizeof err);
    if (!c) {
        fprintf(stderr, "mujoco_rover: %s\n", err);
        return 1;
    }
    if (!terrad_client_world_client_clock(c)) {
        fprintf(stderr, "mujoco_rover: the world ticks on the server's wall clock: lockstep needs "
                        "one with \"clock\": \"client\" (--write-scene writes its scene)\n");
        terrad_client_close(c);
        return 1;
    }
    double dt = 1.0 / terrad_client_world(c)->tick_hz;
    rover r;
    if (rover_load(&r, a->model, dt, err, sizeof err) != 0) {
        fprintf(stderr, "mujoco_rover: %s: %s\n", a->model, err);
        rover_free(&r);
        terrad_client_close(c);
        return 1;
    }
    rover_place(&r);
    int rc = 0;
    for (int i = 0; i < WHEELS && rc == 0; i++)
        rc = terrad_client_create_collider(c,
                                           (terrad_collider_desc){.shape = TERRAD_SHAPE_WHEEL,
                                                                  .radius = WHEEL_RADIUS_M,
                                                                  .width = WHEEL_WIDTH_M},
                                           &r.ids[i]);
    long steps = (long)llround(a->seconds / dt), second = (long)llround(1.0 / dt);
    track t = {calloc((size_t)steps, sizeof(double)),
               calloc((size_t)steps, sizeof(double)),
               calloc((size_t)steps, sizeof(double)),
               0,
               r.d->qpos[0],
               0};
    if (!t.x || !t.slip || !t.sink)
        rc = TERRAD_E_NO_MEMORY;
    double t0 = now_s();
    float fz[WHEELS] = {0};
    while (rc == 0 && t.n < steps && (rc = step(&r, c)) == 0) {
        double slip = 0, sink = 0;
        for (int i = 0; i < WHEELS; i++) {
            double dz = r.f[i].force[2] - fz[i];
            t.chatter += dz * dz;
            fz[i] = r.f[i].force[2];
            slip += r.f[i].slip / WHEELS;
            sink += r.f[i].sinkage_m / WHEELS;
        }
        long k = t.n++;
        t.x[k] = r.d->qpos[0];
        t.slip[k] = slip;
        t.sink[k] = sink;
        if (t.n % second == 0) {
            /* pitch from the chassis' quaternion (qpos 3..6: w, x, y, z) */
            const mjtNum *q = r.d->qpos + 3;
            double pitch = -asin(fmax(-1.0, fmin(1.0, 2 * (q[0] * q[2] - q[3] * q[1]))));
            printf("t %5.1f s  x %5.2f m  v %5.2f m/s  nose up %5.1f deg  slip %4.2f  sinkage "
                   "%5.1f mm\n",
                   t.n * dt, t.x[k], r.d->qvel[0], pitch * 180 / PI,
                   mean(t.slip, t.n - second, t.n), 1e3 * mean(t.sink, t.n - second, t.n));
            fflush(stdout);
        }
        if (t.x[k] > top_x_m())
            break; /* the rear wheels are over the top */
    }
    if (rc == 0)
        verdict(&r, &t, dt, now_s() - t0);
    else
        fprintf(stderr, "mujoco_rover: step %ld: %s (%d)\n", t.n, terrad_client_last_error(c), rc);
    free(t.x);
    free(t.slip);
    free(t.sink);
    rover_free(&r);
    terrad_client_close(c);
    return rc == 0 ? 0 : 1;
}

static const char usage[] =
    "usage: mujoco_rover [--host H] [--port P] [--token T] [--world NAME] [--model FILE.xml]\n"
    "                    [--seconds S]\n"
    "       mujoco_rover --write-scene PRESET DIR [--slip-n X] [--hz HZ]\n";

/* A number in [lo, hi] for option o, or -1 after saying why. */
static int number(const char *o, const char *v, double lo, double hi, double *out)
{
    char *end = NULL;
    double x = v ? strtod(v, &end) : NAN;
    if (!v || end == v || *end || !(x >= lo && x <= hi)) {
        fprintf(stderr, "mujoco_rover: %s: expected a number in [%g, %g] (got \"%s\")\n%s", o, lo,
                hi, v ? v : "", usage);
        return -1;
    }
    *out = x;
    return 0;
}

int main(int argc, char **argv)
{
    args a = {.host = "127.0.0.1", .port = 8081, .model = "mujoco_rover.xml", .seconds = 14};
    const char *scene_soil = NULL, *scene_dir = NULL;
    double slip_n = 0, hz = 500, port = a.port;
    for (int i = 1; i < argc; i++) {
        const char *o = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
        int bad = 0;
        if (strcmp(o, "--help") == 0) {
            fputs(usage, stdout);
            return 0;
        } else if (strcmp(o, "--write-scene") == 0 && i + 2 < argc) {
            scene_soil = argv[++i];
            scene_dir = argv[++i];
            continue;
        } else if (!v)
            bad = 1;
        else if (strcmp(o, "--host") == 0)
            a.host = v;
        else if (strcmp(o, "--token") == 0)
            a.token = v;
        else if (strcmp(o, "--world") == 0)
            a.world = v;
        else if (strcmp(o, "--model") == 0)
            a.model = v;
        else if (strcmp(o, "--port") == 0)
            bad = number(o, v, 1, 65535, &port);
        else if (strcmp(o, "--seconds") == 0)
            bad = number(o, v, 1e-3, 3600, &a.seconds);
        else if (strcmp(o, "--slip-n") == 0)
            bad = number(o, v, 0, 2, &slip_n);
        else if (strcmp(o, "--hz") == 0)
            bad = number(o, v, 1, 10000, &hz);
        else
            bad = 1;
        if (bad) {
            if (bad > 0)
                fprintf(stderr, "mujoco_rover: %s: unknown option or missing value\n%s", o, usage);
            return 2;
        }
        i++;
    }
    a.port = (int)port;
    return scene_soil ? write_scene(scene_soil, slip_n, hz, scene_dir) : drive(&a);
}
