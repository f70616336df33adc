/*
 * http_client_internal.h: the small blocking HTTP/1.0 client of terrad's own
 * commands (app/http_client.c): `terrad loadgen` reads /v1/stats, /metrics
 * and /v1/heights with it, and `terrad world add|list|remove --http URL`
 * calls a node's or daemon's world lifecycle API. Only inside server/app/;
 * never used inside a tick.
 */
#ifndef TERRAD_HTTP_CLIENT_INTERNAL_H
#define TERRAD_HTTP_CLIENT_INTERNAL_H

#include <stddef.h>

/* "http://HOST:PORT[/]" into host and port: 0, or -1 when it is not one. */
int app_http_url(const char *url, char *host, size_t cap, int *port);
/* One request (body: NULL for none; token: "" or NULL for none, else sent as
 * a bearer token). Returns the status with the answer's body (malloc'd,
 * NUL after it) and length, or -1 when it could not be made or read. */
int app_http_request(const char *host, int port, const char *method, const char *path,
                     const char *token, const char *body, size_t body_len, char **answer,
                     size_t *answer_len);

#endif
