/*
 * common.glsl: what every compute stage of the GL backend shares. The loader
 * (server/gl/shader.c) splices this file in where a shader says
 * `#include "common.glsl"`, right after its #version line.
 *
 * A batch is all windows of one tick, packed end to end in flat per-cell
 * buffers: window i owns cells [offset, offset + w*h), row-major. Every
 * dispatch covers the whole batch with one 8x8 workgroup per tile of a
 * window (the tile list is in the batch table), one invocation per cell.
 *
 * Everything here is integer-only and mirrors server/sim/sim_stages.c (the
 * specification): 64-bit quantities of the C code are emulated as uvec2
 * (low word, high word; two's complement), so overflow tests give the same
 * answer as the C's int64 comparisons.
 */

#define CELL_SEED 0
#define CELL_OBSTACLE 1
#define CELL_PENETRATING 2

#define METRIC_EUCLIDEAN 0
#define METRIC_MANHATTAN 1
#define METRIC_CHEBYSHEV 2

#define BOTTOM_NONE 0x7fffffff
#define INT32_MAX_V 0x7fffffff
#define HEIGHT_MAX (1 << 29)
#define HEIGHT_MIN (-(1 << 29))

/* Window status bits (sim_window_status). */
#define STATUS_HEIGHT_LIMIT 1u

struct window_entry {
    int offset;     /* first cell of the window in the flat buffers */
    int x, y;       /* world cell of the window's corner (jump-flood tie hash) */
    int w, h;       /* cells */
    int cast_depth; /* 1: the depth stage computes its bottoms, 0: they were uploaded */
};

/*
 * Reads and writes take different paths. Everything a pass only reads —
 * the batch table and the per-cell inputs — is a buffer texture (texelFetch
 * on an isamplerBuffer over the same buffer object); what it writes is a
 * shader storage buffer. On llvmpipe a texel fetch is a vector gather while
 * a storage-buffer load runs lane by lane, which halves the time of the
 * neighbourhood passes; on a GPU it goes through the texture cache.
 * Samplers and storage blocks have separate binding points: sampler unit 0
 * is the batch table in every pass, storage binding 1 the window status.
 *
 * The batch table (RGBA32I texels): window i at texels 2i .. 2i+1 =
 * (offset, x, y, w), (h, cast_depth, -, -); then, from texel
 * 2 * u_window_count, one
 * texel per 8x8 tile of the batch: (window index, tile corner x | y << 16,
 * the window's offset, w | h << 16). One dispatch runs one workgroup per
 * tile, so an invocation finds its window and cell with one fetch, without
 * searching or dividing.
 */
layout(binding = 0) uniform isamplerBuffer u_table;

layout(std430, binding = 1) coherent buffer window_status {
    uint status[];
};

uniform int u_window_count;
uniform int u_tile_count;

/* Integer parameters (sim_params). */
uniform int u_metric;
uniform int u_obstacle_gap;
uniform int u_multi_target_step;
uniform int u_multi_target_max;
uniform int u_floor;

/* Materials (sim_stages.c): row id holds (compression_q16, roughness_q16,
 * threshold axial, diagonal). u_materials_on 0: no material buffer, every
 * cell is row 0 (the uniform path, a one-row table of the params);
 * otherwise each cell's material word is id | memory << 8. */
uniform int u_materials_on;
uniform int u_material_count;
uniform ivec4 u_material_rows[16];
uniform int u_material_max_compaction[16];

int material_id(int word)
{
    int id = word & 255;
    return id < u_material_count ? id : 0;
}

/* 8-neighbourhood; the first four are axial, the last four diagonal. */
const int neighbour_dx[8] = int[8](1, -1, 0, 0, 1, -1, 1, -1);
const int neighbour_dy[8] = int[8](0, 0, 1, -1, 1, 1, -1, -1);

window_entry window_at(int i)
{
    ivec4 a = texelFetch(u_table, 2 * i);
    ivec4 b = texelFetch(u_table, 2 * i + 1);
    return window_entry(a.x, a.y, a.z, a.w, b.x, b.y);
}

/* One int of a per-cell input. */
int fetch(isamplerBuffer buf, int i)
{
    return texelFetch(buf, i).x;
}

/* The window of the batch that a cell is in: what most stages need. */
struct cell_window {
    int index;  /* in the batch (status flags, window_at) */
    int offset; /* first cell of the window in the flat buffers */
    int w, h;
};

/* Tile `tile`'s texel of the batch table: (window index, corner x | y << 16,
 * the window's offset, w | h << 16). */
ivec4 tile_entry(uint tile)
{
    return texelFetch(u_table, 2 * u_window_count + int(tile));
}

/*
 * This invocation's cell in tile `tile` of the batch table (locate_cell:
 * the workgroup's own tile; jump_flood.comp: a tile of the compacted list):
 * its window, the window-local coordinates and the flat index. False for
 * invocations past the batch or outside their window (tiles overhang a
 * window's right and top edges). Dispatches are 2D grids of tiles so that
 * batches beyond 65535 tiles fit.
 */
bool locate_tile_cell(uint tile, out cell_window win, out int x, out int y, out int c)
{
    win = cell_window(0, 0, 1, 1);
    x = 0;
    y = 0;
    c = 0;
    if (tile >= uint(u_tile_count))
        return false;
    ivec4 t = tile_entry(tile);
    win = cell_window(t.x, t.z, t.w & 0xffff, t.w >> 16);
    x = (t.y & 0xffff) + int(gl_LocalInvocationID.x);
    y = (t.y >> 16) + int(gl_LocalInvocationID.y);
    c = win.offset + y * win.w + x;
    return x < win.w && y < win.h;
}

bool locate_cell(out cell_window win, out int x, out int y, out int c)
{
    return locate_tile_cell(gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x, win, x, y,
                            c);
}

/* Seeds are stored as window-local coordinates x | y << 16 rather than the
 * C's index y * w + x: the same order (so ties break the same way), and no
 * division to get the coordinates back. -1: no seed. */
int seed_pack(int x, int y)
{
    return x | (y << 16);
}

int seed_x(int s)
{
    return s & 0xffff;
}

int seed_y(int s)
{
    return s >> 16;
}

/* A window already refused at the height limit: later passes may skip it. */
bool window_refused(int win)
{
    return (status[win] & STATUS_HEIGHT_LIMIT) != 0u;
}

void refuse_window(int win)
{
    atomicOr(status[win], STATUS_HEIGHT_LIMIT);
}

/* sim_cell_hash: identical arithmetic in uint (wrapping multiplies). */
uint cell_hash(int world_x, int world_y)
{
    uint h = uint(world_x) * 0x8da6b343u ^ uint(world_y) * 0xd8163841u;
    h ^= h >> 16;
    h *= 0x7feb352du;
    h ^= h >> 15;
    h *= 0x846ca68bu;
    h ^= h >> 16;
    return h;
}

/* sim_metric_distance; Euclidean is squared. */
int metric_distance(int dx, int dy)
{
    int ax = abs(dx), ay = abs(dy);
    if (u_metric == METRIC_MANHATTAN)
        return ax + ay;
    if (u_metric == METRIC_CHEBYSHEV)
        return max(ax, ay);
    return ax * ax + ay * ay;
}

/* mul_q16_shift: (uint64(a) * q16) >> shift, truncated to 32 bits, for
 * 0 < shift < 32: the 64-bit product comes from umulExtended. */
int mul_q16_shift(int a, int q16, int shift)
{
    uint hi, lo;
    umulExtended(uint(a), uint(q16), hi, lo);
    return int((hi << uint(32 - shift)) | (lo >> uint(shift)));
}

/* ---- int64 as uvec2(low, high), two's complement ---- */

uvec2 i64(int a)
{
    return uvec2(uint(a), a < 0 ? 0xffffffffu : 0u);
}

uvec2 i64_add(uvec2 a, uvec2 b)
{
    uint carry;
    uint lo = uaddCarry(a.x, b.x, carry);
    return uvec2(lo, a.y + b.y + carry);
}

uvec2 i64_sub(uvec2 a, uvec2 b)
{
    uint borrow;
    uint lo = usubBorrow(a.x, b.x, borrow);
    return uvec2(lo, a.y - b.y - borrow);
}

bool i64_gt(uvec2 a, uvec2 b)
{
    if (a.y != b.y)
        return int(a.y) > int(b.y);
    return a.x > b.x;
}
