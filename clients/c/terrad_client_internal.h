/*
 * terrad_client_internal.h: what terrad_client.c and terrad_client_predict.c
 * (the prediction, docs/engines.md "Prediction") share inside the client
 * library. Not installed; nothing here is part of libterrad-client's ABI (the
 * symbols are hidden from the shared library).
 */
#ifndef TERRAD_CLIENT_INTERNAL_H
#define TERRAD_CLIENT_INTERNAL_H

#include "terrad_client.h"

#define TERRAD_CLIENT_HIDDEN __attribute__((visibility("hidden")))

/* A collider this client created: what a prediction needs to make its copy. */
typedef struct client_own {
    uint32_t id;
    terrad_shape shape;
    double radius, half_length, width, half_extents[3];
    int default_material; /* only these are predicted (the twin holds the default material) */
    terrad_grousers lugs; /* a wheel's grousers (count 0: smooth), pressed by the twin too */
    double load_n;        /* > 0: load-driven, its height the soil's in the twin too */
} client_own;

/* terrad_client.c's side. */
TERRAD_CLIENT_HIDDEN const client_own *client_own_colliders(const terrad_client *c, size_t *n);
TERRAD_CLIENT_HIDDEN terrad_prediction **client_predictions(terrad_client *c);
TERRAD_CLIENT_HIDDEN void client_set_error(terrad_client *c, const char *fmt, ...)
    __attribute__((format(printf, 2, 3)));

/* terrad_client_base.c: the base terrain over (x, y, w, h) into out, from the
 * world message's "base" (the scene's twin config); -1 with err. */
struct cJSON;
TERRAD_CLIENT_HIDDEN int client_base_fill(const struct cJSON *base, int x, int y, int w, int h,
                                          int32_t *out, char *err, size_t cap);

/* terrad_client_predict.c's side: called by the client at each event. */
/* Batch seq was queued and has not left yet: every prediction ticks it. */
TERRAD_CLIENT_HIDDEN void predict_sent(terrad_client *c, uint32_t seq, const terrad_pose *poses,
                                       size_t count);
/* An ACK of tick (batch seq); the mirrors hold the server's heights at tick. */
TERRAD_CLIENT_HIDDEN void predict_acked(terrad_client *c, uint64_t tick, uint32_t seq);
/* A collider of this client was created (added 1) or deleted (0). */
TERRAD_CLIENT_HIDDEN void predict_collider(terrad_client *c, const client_own *o, int added);
/* The client closes: every prediction is freed. */
TERRAD_CLIENT_HIDDEN void predict_free_all(terrad_client *c);

#endif /* TERRAD_CLIENT_INTERNAL_H */
