/*
 * net_remote_send.c: what the net thread sends another node (docs/cluster.md;
 * the two roles are described in net_remote.c): a relay's client messages go
 * to the world's owner as they came, a remote client's frames and its close
 * go back to its relay. A leaf of net/ (the layers are listed in
 * net_client_internal.h): it only fills a net_remote_msg and calls the
 * state's remote_send (the cluster's publish, set by net_server_set_remote),
 * so the client records, the requests and the fan-out can all use it. In a
 * tick's terms: it runs wherever the net thread would have queued a frame
 * for a local client.
 */
#include "net/net_client_internal.h"

#include <stdio.h>
#include <string.h>

void net_relay_forward(net_client *c, int binary, const void *data, size_t len)
{
    net_state *w = c->srv;
    net_remote_msg m = {.kind = binary ? NET_REMOTE_CLIENT_BINARY : NET_REMOTE_CLIENT_TEXT,
                        .client = c->id};
    snprintf(m.node, sizeof m.node, "%s", w->node);
    w->remote_send(w->remote_ctx, w->world_name, &m, data, len);
}

void net_remote_frame(net_client *c, const hub_frame *f, int snapshot_done)
{
    net_state *w = c->srv;
    net_remote_msg m = {.kind = NET_REMOTE_FRAME,
                        .client = c->remote_client,
                        .binary = f ? f->binary : 0,
                        .snapshot_done = snapshot_done,
                        .tick = w->tick};
    snprintf(m.node, sizeof m.node, "%s", c->remote_node);
    w->remote_send(w->remote_ctx, w->world_name, &m, f ? f->data : NULL, f ? f->len : 0);
}

void net_remote_close(net_client *c, int code, const char *reason)
{
    net_state *w = c->srv;
    c->closing = 1;
    if (c->remote_gone)
        return;
    c->remote_gone = 1; /* freed by net_remote_apply */
    net_remote_msg m = {.kind = NET_REMOTE_CLOSE, .client = c->remote_client, .close_code = code};
    snprintf(m.node, sizeof m.node, "%s", c->remote_node);
    w->remote_send(w->remote_ctx, w->world_name, &m, reason, strlen(reason));
}
