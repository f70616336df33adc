/*
 * http_internal.h: what http.c shares with http_auth.c inside server/http/
 * — who may read (a bearer token's role) and the TLS pair libmicrohttpd
 * serves HTTPS with. Not part of the face of http/ (that is http.h).
 */
#ifndef TERRAD_HTTP_INTERNAL_H
#define TERRAD_HTTP_INTERNAL_H

#include <microhttpd.h>

#include "http/http.h"

/* The PEM texts libmicrohttpd's GnuTLS reads (it keeps pointers to them for
 * the daemon's life), and the option list that hands them over: empty (only
 * MHD_OPTION_END) without TLS. */
typedef struct http_tls {
    char *cert, *key;
    struct MHD_OptionItem options[3];
} http_tls;

/* Reads sec's files (already checked with tls_check_pair); sec NULL or without
 * files: no TLS. 0, or -1 with err naming the file. */
int http_tls_load(http_tls *t, const http_security *sec, error_text *err);
void http_tls_free(http_tls *t);
int http_tls_on(const http_tls *t);

/* The data endpoints' gate (url: /v1/world, /v1/stats, /v1/heights; any other
 * passes): with auth on, the request must carry
 * "Authorization: Bearer TOKEN" of a known token (any role). NULL when it
 * may go on, else a 401 response (JSON error, WWW-Authenticate) to queue;
 * the refusal is counted in terrad_auth_refused_total{reason="bad_token"}. */
struct MHD_Response *http_auth_refusal(struct MHD_Connection *c, const char *url, auth_table *auth);

#endif
