/*
 * lugs_json.c: a wheel's "grousers" object, as a scene file and the
 * websocket's collider_create both write it (docs/scene-format.md,
 * proto/PROTOCOL.md): {"count": N, "height": m, "thickness": m}. One reader
 * for both, so a scene's wheel and a client's wheel are refused with the same
 * words; the sizes against the rim are collider_geometry_validate's (lugs.c
 * presses them in the depth stage). Outside the twin library (no cJSON there).
 */
#include "collider/collider.h"

#include <cjson/cJSON.h>

int collider_grousers_from_json(const cJSON *obj, const char *path, collider_grousers *out,
                                error_text *err)
{
    *out = (collider_grousers){0};
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(obj, "grousers");
    if (!v)
        return 0;
    char p[256];
    json_path_join(p, sizeof p, path, "grousers");
    static const char *const keys[] = {"count", "height", "thickness", NULL};
    if (json_expect_object(v, p, "grousers", err) ||
        json_check_keys(v, p, keys, "grousers (count, height, thickness)", err))
        return -1;
    double count = 0;
    if (json_get_integer(v, p, "count", 1, COLLIDER_GROUSERS_MAX, 1, &count, err) < 0 ||
        json_get_positive(v, p, "height", 1000, 1, &out->height, err) < 0 ||
        json_get_positive(v, p, "thickness", 1000, 1, &out->thickness, err) < 0)
        return -1;
    out->count = (int)count;
    return 1;
}
