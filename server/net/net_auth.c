/*
 * net_auth.c: roles on the websocket side (PROTOCOL.md "Roles"), in the
 * middle layer of the net thread beside net_requests.c. A hello's token
 * gives its client a role for the connection's life: viewer (subscribe,
 * read), driver (its own colliders, created, posed and deleted), admin
 * (everything, and deleting any client's collider). Requests a role does not
 * allow are refused with `forbidden` and counted; they never reach the hub,
 * so the tick does not see them.
 *
 * Revocation: the app reloads the table on SIGHUP (between ticks); the
 * heartbeat sees the generation move and looks every client's token hash up
 * again. A client whose token is gone is closed with 4013, one whose role
 * changed gets the new role.
 */
#include <string.h>

#include "metrics/metrics.h"
#include "net/net_requests_internal.h"
#include "terrad_proto.h"

int net_auth_start(net_state *s, error_text *err)
{
    if (s->cfg.auth) {
        s->auth = s->cfg.auth;
    } else {
        s->auth = auth_create(NULL, err);
        if (!s->auth)
            return -1;
        s->own_auth = 1;
    }
    s->auth_generation = auth_generation(s->auth);
    return 0;
}

void net_auth_stop(net_state *s)
{
    if (s->own_auth)
        auth_free(s->auth);
    s->auth = NULL;
    s->own_auth = 0;
}

int net_auth_hello(net_client *c, const char *token, const cJSON *ref)
{
    net_state *s = c->srv;
    c->role = auth_check(s->auth, token, c->auth_name, sizeof c->auth_name, c->token_hash);
    if (c->role != AUTH_NONE)
        return 0;
    metrics_count_auth_refused("bad_token");
    net_error(c, TERRAD_E_UNAUTHORIZED, ref, -1, 1, "token: %s",
              token[0] ? "not a known token (wrong, or revoked)" : "this server needs a token");
    net_close_after_flush(c, 4000 + TERRAD_E_UNAUTHORIZED, "unauthorized");
    return -1;
}

int net_auth_allows(net_client *c, auth_role needed, const char *what, const cJSON *ref)
{
    if (c->role >= needed)
        return 1;
    metrics_count_auth_refused("forbidden");
    net_error(c, TERRAD_E_FORBIDDEN, ref, -1, 0,
              "%s: forbidden for role %s (token \"%s\"); it needs role %s or above", what,
              auth_role_name(c->role), c->auth_name, auth_role_name(needed));
    return 0;
}

void net_auth_recheck(net_state *s)
{
    unsigned gen = auth_generation(s->auth);
    if (gen == s->auth_generation)
        return;
    s->auth_generation = gen;
    int closed = 0;
    for (int i = 0; i < s->nclients; i++) {
        net_client *c = s->clients[i];
        if (!c->ready || c->closing || c->killed)
            continue;
        auth_role r = auth_role_of_hash(s->auth, c->token_hash);
        if (r == c->role)
            continue;
        if (r != AUTH_NONE) {
            log_info("net: client %u (%s): token \"%s\" is now role %s (was %s)", c->id, c->name,
                     c->auth_name, auth_role_name(r), auth_role_name(c->role));
            c->role = r;
            continue;
        }
        metrics_count_auth_refused("revoked");
        c->role = AUTH_NONE;
        net_error(c, TERRAD_E_UNAUTHORIZED, NULL, -1, 1,
                  "token \"%s\" was revoked (the auth file was reloaded)", c->auth_name);
        net_close_after_flush(c, 4000 + TERRAD_E_UNAUTHORIZED, "token revoked");
        closed++;
    }
    log_info("net: auth reloaded: %d clients closed for revoked tokens", closed);
}
