/*
 * terrad_client_base.c: the scene's base terrain for base snapshots
 * (PROTOCOL.md "Base snapshots", issue 32 item 2). A client that connected
 * with terrad_client_connect_base gets each snapshot as its heights less the
 * base; this file rebuilds the base over a subscription's region with the
 * twin library (the same code that made the server's world), from the world
 * message's "base" (the scene's twin config), so that terrad_mirror_apply can
 * add it back. Called once per subscription, when the server says
 * "subscribed", before any of its snapshot frames are read.
 */
#include "terrad_client_internal.h"
#include "terrad_twin.h"

#include <cjson/cJSON.h>
#include <stdio.h>

int client_base_fill(const cJSON *base, int x, int y, int w, int h, int32_t *out, char *err,
                     size_t cap)
{
    char why[TERRAD_TWIN_ERROR_MAX] = "";
    terrad_twin_config *cfg = terrad_twin_config_new();
    int rc = cfg ? 0 : -1;
    const cJSON *it;
    cJSON_ArrayForEach(it, base)
    {
        if (rc)
            break;
        if (cJSON_IsNumber(it))
            rc = terrad_twin_config_set(cfg, it->string, it->valuedouble, why);
        else if (cJSON_IsString(it))
            rc = terrad_twin_config_set_name(cfg, it->string, it->valuestring, why);
    }
    terrad_twin *t = rc == 0 ? terrad_twin_create(cfg, x, y, w, h, NULL, why) : NULL;
    rc = t && terrad_twin_read(t, x, y, w, h, out, why) == 0 ? 0 : -1;
    if (rc && err && cap)
        snprintf(err, cap, "base: %s", why[0] ? why : "out of memory");
    terrad_twin_destroy(t);
    terrad_twin_config_free(cfg);
    return rc;
}
