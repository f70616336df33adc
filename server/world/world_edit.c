/*
 * world_edit.c: terrain edits from game logic (issue 22) — a crater, a
 * stamped height patch, a rectangle reset to the base terrain, material
 * added or removed over an area — applied to the world's heights (the
 * protocol's `edit` message, PROTOCOL.md "edit", is parsed into a world_edit
 * beside the other wire input, hub/hub_edit.c). The service
 * applies them at the start of a tick, before the colliders deform, in the
 * order they arrived (service_edits.c); the WAL logs and the deltas carry
 * the cells they changed like any other change.
 *
 * Everything here is integer arithmetic on the heights, so an edit gives
 * the same cells on every backend and thread count. An edit is applied
 * whole or not at one: one that would move a cell outside
 * [WORLD_HEIGHT_MIN, WORLD_HEIGHT_MAX] changes nothing. The change is
 * returned as per-cell differences; their sum is the exact volume change
 * the reply declares (a crater with its rim keeps Σh exactly: the dug
 * volume is shared out over the rim with the remainder handed out unit by
 * unit in raster order).
 */
#include "world/world.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const char *const op_names[] = {"crater", "stamp", "reset", "add", "remove"};

const char *world_edit_op_name(world_edit_op op)
{
    return op >= 0 && op < (int)(sizeof op_names / sizeof op_names[0]) ? op_names[op] : "?";
}

void world_edit_free(world_edit *e)
{
    free(e->values);
    free(e->mask);
    e->values = NULL;
    e->mask = NULL;
}

/* ---- applying ---- */

/* The crater's new heights in h (e->rect, row-major). */
static void crater_heights(const world_edit *e, int64_t *h)
{
    const world_rect r = e->rect;
    const int64_t r2 = (int64_t)e->radius * e->radius;
    int64_t dug = 0, weights = 0, rim_cells = 0;
    for (int y = r.y; y < r.y + r.h; y++)
        for (int x = r.x; x < r.x + r.w; x++) {
            int64_t dx = x - e->cx, dy = y - e->cy, d2 = dx * dx + dy * dy;
            int64_t i = (int64_t)(y - r.y) * r.w + (x - r.x);
            if (d2 < r2) { /* a paraboloid bowl: depth at the centre, 0 at the radius */
                int64_t dig = e->depth * (r2 - d2) / r2;
                h[i] -= dig;
                dug += dig;
            } else if (e->rim && d2 < 4 * r2) {
                weights += 4 * r2 - d2; /* highest at the edge, 0 at twice the radius */
                rim_cells++;
            }
        }
    if (!e->rim || rim_cells == 0 || dug == 0)
        return;
    /* share dug out by weight, exactly: q * w + (rem * w) / W per cell, then
     * what floor division left (fewer units than rim cells) one by one */
    int64_t q = dug / weights, rem = dug % weights, given = 0;
    for (int pass = 0; pass < 2; pass++)
        for (int y = r.y; y < r.y + r.h; y++)
            for (int x = r.x; x < r.x + r.w; x++) {
                int64_t dx = x - e->cx, dy = y - e->cy, d2 = dx * dx + dy * dy;
                if (d2 < r2 || d2 >= 4 * r2)
                    continue;
                int64_t i = (int64_t)(y - r.y) * r.w + (x - r.x);
                if (pass == 0) {
                    int64_t wgt = 4 * r2 - d2, share = q * wgt + rem * wgt / weights;
                    h[i] += share;
                    given += share;
                } else if (given < dug) {
                    h[i] += 1;
                    given++;
                }
            }
}

int world_edit_apply(world *w, const world_edit *e, world_rect *rect, int32_t **diff,
                     int64_t *volume, error_text *err)
{
    const world_rect r = e->rect;
    size_t cells = (size_t)r.w * r.h;
    int32_t *before = malloc(cells * sizeof *before);
    int64_t *h = malloc(cells * sizeof *h);
    if (!before || !h) {
        free(before);
        free(h);
        error_set(err, "edit: out of memory for %zu cells", cells);
        return -1;
    }
    if (e->op == WORLD_EDIT_RESET) {
        world_base_fill_rect(w, r, before);
        for (size_t i = 0; i < cells; i++)
            h[i] = before[i];
    }
    world_gather_window(w, r, before);
    if (e->op != WORLD_EDIT_RESET)
        for (size_t i = 0; i < cells; i++)
            h[i] = before[i];
    if (e->op == WORLD_EDIT_CRATER)
        crater_heights(e, h);
    for (size_t i = 0; i < cells && e->op != WORLD_EDIT_CRATER && e->op != WORLD_EDIT_RESET; i++) {
        if (e->op == WORLD_EDIT_ADD)
            h[i] += e->amount;
        else if (e->op == WORLD_EDIT_REMOVE)
            h[i] -= e->amount;
        else if (!e->mask || e->mask[i]) { /* stamp */
            int64_t v = e->values[i];
            h[i] = e->mode == WORLD_STAMP_SET   ? v
                   : e->mode == WORLD_STAMP_ADD ? h[i] + v
                   : e->mode == WORLD_STAMP_MIN ? (v < h[i] ? v : h[i])
                                                : (v > h[i] ? v : h[i]);
        }
    }
    int64_t sum = 0;
    for (size_t i = 0; i < cells; i++) {
        if (h[i] < WORLD_HEIGHT_MIN || h[i] > WORLD_HEIGHT_MAX) {
            int x = r.x + (int)(i % (size_t)r.w), y = r.y + (int)(i / (size_t)r.w);
            error_set(err,
                      "%s: cell (%d, %d) would be at %lld units, outside the height range "
                      "[%d, %d]; nothing was changed",
                      world_edit_op_name(e->op), x, y, (long long)h[i], WORLD_HEIGHT_MIN,
                      WORLD_HEIGHT_MAX);
            free(before);
            free(h);
            return -1;
        }
        int32_t d = (int32_t)(h[i] - before[i]);
        sum += d;
        before[i] = (int32_t)h[i]; /* before now holds the new heights */
        h[i] = d;
    }
    world_scatter_window(w, r, before);
    /* the differences, narrowed into before's buffer (|d| < 2^30) */
    for (size_t i = 0; i < cells; i++)
        before[i] = (int32_t)h[i];
    free(h);
    *rect = r;
    *diff = before;
    *volume = sum;
    return 0;
}

/* Cell by cell: an undo follows a failed log write and must not itself
 * fail for want of memory; it is rare, so its speed does not matter. */
void world_edit_undo(world *w, world_rect r, const int32_t *diff)
{
    for (int y = r.y; y < r.y + r.h; y++)
        for (int x = r.x; x < r.x + r.w; x++) {
            int32_t d = diff[(int64_t)(y - r.y) * r.w + (x - r.x)];
            if (d)
                world_set_height(w, x, y, world_height_at(w, x, y) - d);
        }
}
