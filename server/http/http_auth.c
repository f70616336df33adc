/*
 * http_auth.c: bearer tokens and TLS for the HTTP side (http_internal.h).
 * Runs on libmicrohttpd's threads, never on the sim thread: a token check
 * is one SHA-256 and a read-locked table scan (base.h "Authentication"),
 * and a reload between ticks takes effect for the next request.
 *
 * What needs a token when auth is on: the data endpoints /v1/world, /v1/twin,
 * /v1/stats and /v1/heights (any role: HTTP only reads). What never does:
 * the probes and /metrics (a load balancer or Prometheus has no token to
 * give), /v1/openapi.yaml and the viewer's static files (the viewer sends
 * its token in the websocket hello).
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include "http/http_internal.h"
#include "metrics/metrics.h"

int http_tls_load(http_tls *t, const http_security *sec, error_text *err)
{
    memset(t, 0, sizeof *t);
    t->options[0] = (struct MHD_OptionItem){MHD_OPTION_END, 0, NULL};
    if (!sec || !sec->tls_cert || !sec->tls_key)
        return 0;
    uint8_t *cert = NULL, *key = NULL;
    size_t n;
    if (file_read_all(sec->tls_cert, 1u << 20, &cert, &n, err) != 0 ||
        file_read_all(sec->tls_key, 1u << 20, &key, &n, err) != 0) {
        free(cert);
        error_prefix(err, "http: TLS", " ");
        return -1;
    }
    t->cert = (char *)cert; /* file_read_all ends the text with a NUL */
    t->key = (char *)key;
    t->options[0] = (struct MHD_OptionItem){MHD_OPTION_HTTPS_MEM_KEY, 0, t->key};
    t->options[1] = (struct MHD_OptionItem){MHD_OPTION_HTTPS_MEM_CERT, 0, t->cert};
    t->options[2] = (struct MHD_OptionItem){MHD_OPTION_END, 0, NULL};
    return 0;
}

void http_tls_free(http_tls *t)
{
    if (t->key)
        memset(t->key, 0, strlen(t->key));
    free(t->key);
    free(t->cert);
    t->key = t->cert = NULL;
}

int http_tls_on(const http_tls *t)
{
    return t->cert != NULL;
}

struct MHD_Response *http_auth_refusal(struct MHD_Connection *c, const char *url, auth_table *auth)
{
    if (!auth_enabled(auth) || (strcmp(url, "/v1/world") != 0 && strcmp(url, "/v1/stats") != 0 &&
                                strcmp(url, "/v1/heights") != 0 && strcmp(url, "/v1/twin") != 0))
        return NULL;
    const char *h = MHD_lookup_connection_value(c, MHD_HEADER_KIND, "Authorization");
    const char *token = NULL;
    if (h && strncasecmp(h, "Bearer ", 7) == 0) {
        token = h + 7;
        while (*token == ' ')
            token++;
    }
    if (token && *token && auth_check(auth, token, NULL, 0, NULL) != AUTH_NONE)
        return NULL;
    metrics_count_auth_refused("bad_token");
    char body[200];
    snprintf(body, sizeof body,
             "{\"error\":\"%s: send \\\"Authorization: Bearer TOKEN\\\" with a token of any "
             "role\"}\n",
             token && *token ? "not a known token (wrong, or revoked)"
                             : "this server needs a token");
    struct MHD_Response *r =
        MHD_create_response_from_buffer(strlen(body), body, MHD_RESPMEM_MUST_COPY);
    if (r) {
        MHD_add_response_header(r, "Content-Type", "application/json");
        MHD_add_response_header(r, "Cache-Control", "no-store");
        MHD_add_response_header(r, "WWW-Authenticate", "Bearer realm=\"terrad\"");
    }
    return r;
}

unsigned http_role_refusal(struct MHD_Connection *c, auth_table *auth, auth_role least,
                           const char *what, char *why, size_t cap)
{
    if (!auth_enabled(auth))
        return 0;
    const char *h = MHD_lookup_connection_value(c, MHD_HEADER_KIND, "Authorization");
    const char *token = h && strncasecmp(h, "Bearer ", 7) == 0 ? h + 7 : NULL;
    while (token && *token == ' ')
        token++;
    auth_role role = token && *token ? auth_check(auth, token, NULL, 0, NULL) : AUTH_NONE;
    if (role == AUTH_NONE) {
        metrics_count_auth_refused("bad_token");
        snprintf(why, cap, "send \"Authorization: Bearer TOKEN\" with a %s token",
                 least >= AUTH_ADMIN    ? "an admin"
                 : least >= AUTH_DRIVER ? "driver or admin"
                                        : "known");
        return MHD_HTTP_UNAUTHORIZED;
    }
    if (role < least) {
        metrics_count_auth_refused("forbidden");
        snprintf(why, cap, "token: the %s role may not %s (%s)", auth_role_name(role), what,
                 least >= AUTH_ADMIN ? "admin only" : "driver or admin");
        return MHD_HTTP_FORBIDDEN;
    }
    return 0;
}
