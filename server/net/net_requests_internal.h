/*
 * net_requests_internal.h: the middle layer of the net thread (see net_client_internal.h) —
 * what a client's whole message asks for, checked and answered, turned into
 * hub commands and poses. Called by net_callback.c (and net_remote.c, for a
 * remote client) with one reassembled message; calls only net_auth.c,
 * net_client.c, net_control.c and net_remote_send.c. Net thread only.
 */
#ifndef TERRAD_NET_REQUESTS_INTERNAL_H
#define TERRAD_NET_REQUESTS_INTERNAL_H

#include <stddef.h>

#include "net/net_client_internal.h"

/* A text message (NUL-terminated at text[len]). */
void net_handle_text(net_client *c, const char *text, size_t len);
/* A binary message (POSE_BATCH, PING, PONG). */
void net_handle_binary(net_client *c, const unsigned char *data, size_t len);

/* ---- a client-clocked world's STEP (net_steps.c) ---- */
/* Checked (each refusal names its field, counted in
 * terrad_steps_refused_total{field}) and queued for the world's ticks; the
 * first accepted STEP makes c the world's driver until it leaves. */
void net_handle_step(net_client *c, const unsigned char *data, size_t len);

/* ---- who may do what (net_auth.c) ---- */
/* s->auth: cfg.auth, or an empty one (auth off). 0, or -1 with err. */
int net_auth_start(net_state *s, error_text *err);
void net_auth_stop(net_state *s);
/* A hello's token: 0 with c's role set, or -1 after an unauthorized error and close. */
int net_auth_hello(net_client *c, const char *token, const cJSON *ref);
/* 1 when c's role is at least `needed`; else 0 after a forbidden error naming
 * the role and `what` (and the metric). */
int net_auth_allows(net_client *c, auth_role needed, const char *what, const cJSON *ref);
/* After a reload (the table's generation moved): each client's role looked up
 * again; a client whose token is gone is closed (4013). Heartbeat, net thread. */
void net_auth_recheck(net_state *s);

#endif
