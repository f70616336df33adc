/*
 * fuzz_control: libFuzzer target for the JSON control-message parser
 * (server/net/net_control_internal.h), the one piece of the net thread that reads
 * what clients write as text. Seeds: tests/fuzz/corpus/fuzz_control/ (one
 * message of each kind, written by hand: the wire vectors hold no JSON).
 *
 * Oracles besides the sanitizers: the parser is a pure function (the same
 * text gives the same result twice); a refusal has a wire error code and a
 * message, and only bad_version is fatal; an accepted request is one of the
 * known kinds with a valid ref, and what it carries is what the sim may be
 * given: a rectangle inside the world, a geometry the collider module
 * accepts, a material of the world's, a pose that is absent or valid.
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "net/net_control_internal.h"
#include "terrad_proto.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static void check_accepted(const net_control *m, const net_control_context *ctx)
{
    error_text e;
    if (m->kind == NET_CONTROL_NONE)
        abort();
    if (m->ref && !cJSON_IsString(m->ref) && !cJSON_IsNumber(m->ref))
        abort();
    switch (m->kind) {
    case NET_CONTROL_SUBSCRIBE:
        if (m->rect.x < 0 || m->rect.y < 0 || m->rect.w < 1 || m->rect.h < 1 ||
            (int64_t)m->rect.x + m->rect.w > ctx->world_width ||
            (int64_t)m->rect.y + m->rect.h > ctx->world_height)
            abort();
        break;
    case NET_CONTROL_COLLIDER_CREATE: {
        if (collider_geometry_validate(&m->geometry, &e) != 0)
            abort();
        if ((m->geometry.shape == COLLIDER_MESH) != (m->mesh != NULL))
            abort();
        int known = 0;
        const cJSON *it;
        cJSON_ArrayForEach(it, ctx->materials) known |= strcmp(it->valuestring, m->material) == 0;
        if (!known)
            abort();
        const quatd *q = &m->pose.orientation;
        int posed = q->w != 0 || q->x != 0 || q->y != 0 || q->z != 0;
        if (posed && collider_pose_validate(&m->pose, &e) != 0)
            abort();
        break;
    }
    case NET_CONTROL_RESYNC: /* tiles inside the world: tile * tile_size is an int */
        for (int i = 0; i < m->tile_count; i++)
            if (m->tiles[2 * i] < 0 || m->tiles[2 * i + 1] < 0 ||
                (int64_t)m->tiles[2 * i] * ctx->tile_size >= ctx->world_width ||
                (int64_t)m->tiles[2 * i + 1] * ctx->tile_size >= ctx->world_height)
                abort();
        break;
    case NET_CONTROL_HELLO:
        if (m->protocol != TERRAD_PROTO_VERSION || strlen(m->client) > NET_CLIENT_NAME_MAX_BYTES)
            abort();
        break;
    default:
        break;
    }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static cJSON *materials;
    static net_limits limits;
    if (!materials) {
        materials = cJSON_Parse("[\"default\", \"sand\"]");
        limits = net_limits_default();
    }
    net_control_context ctx = {.limits = &limits,
                               .materials = materials,
                               .world_width = 512,
                               .world_height = 384,
                               .tile_size = 64};
    net_control a, b;
    net_control_error ea, eb;
    int ra = net_control_parse((const char *)data, size, &ctx, &a, &ea);
    int rb = net_control_parse((const char *)data, size, &ctx, &b, &eb);
    if (ra != rb || a.kind != b.kind || ea.code != eb.code || strcmp(ea.message, eb.message) != 0)
        abort(); /* not a pure function */
    if (ra == 0) {
        if (ea.code != 0)
            abort();
        check_accepted(&a, &ctx);
    } else {
        if (ea.code <= 0 || ea.code > TERRAD_ERR_LAST || ea.message[0] == 0 ||
            memchr(ea.message, 0, sizeof ea.message) == NULL)
            abort();
        if (ea.fatal != (ea.code == TERRAD_E_BAD_VERSION))
            abort();
        if (ea.code == TERRAD_E_UNKNOWN_TYPE && a.kind != NET_CONTROL_NONE)
            abort();
    }
    net_control_free(&a);
    net_control_free(&b);
    return 0;
}
