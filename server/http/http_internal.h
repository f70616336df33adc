/*
 * http_internal.h: what the files of server/http share; not part of the face
 * of http/ (that is http.h).
 *
 *   http.c        the MHD daemon, routing, probes, the /v1 answers
 *   http_png.c    /v1/heights?format=png16
 *   http_guard.c  what one address may hold: heights bytes in flight, and the
 *                 deadline for a request's headers (slowloris)
 */
#ifndef TERRAD_HTTP_INTERNAL_H
#define TERRAD_HTTP_INTERNAL_H

#include "http/http.h"

#include <microhttpd.h>
#include <stddef.h>
#include <stdint.h>

/* ---- http_png.c ---- */
typedef struct http_png_memory {
    unsigned char *data;
    size_t len;
    int64_t cap;
} http_png_memory;

/* Heights → 16-bit greyscale PNG, value = clamp(h - offset, 0, 65535) with
 * offset = the rectangle's minimum, so the image inverts exactly whenever the
 * rectangle's range fits 16 bits (*clipped says whether it did). Returns 0,
 * or -1 with out->data freed. */
int http_png16_encode(const int32_t *heights, int w, int h, int32_t *offset, int *clipped,
                      http_png_memory *out);

/* ---- http_guard.c ---- */
typedef struct http_guard http_guard;

/* A guard for one listener: heights answers may hold at most per_address
 * bytes for one client address and total bytes in all; a connection that has
 * not sent a whole request's headers header_deadline_s after it opened (or
 * after its previous request ended) is cut. Starts its sweeper thread. */
http_guard *http_guard_start(size_t per_address, size_t total, unsigned header_deadline_s);
void http_guard_stop(http_guard *g); /* after MHD_stop_daemon */
/* MHD_OPTION_NOTIFY_CONNECTION (cls: the guard). */
void http_guard_notify(void *cls, struct MHD_Connection *c, void **socket_context,
                       enum MHD_ConnectionNotificationCode code);
/* The handler has seen the request's headers: no deadline until it ends. */
void http_guard_headers_done(http_guard *g, struct MHD_Connection *c);
/* Reserve bytes of a heights answer for c's address until its request ends:
 * 0, or -1 (nothing reserved) when the address or everyone is over budget. */
int http_guard_reserve(http_guard *g, struct MHD_Connection *c, size_t bytes);
/* The request ended (sent, timed out, or the peer left): its bytes are
 * released, the next request's headers are awaited from now. */
void http_guard_request_done(http_guard *g, struct MHD_Connection *c);

#endif
