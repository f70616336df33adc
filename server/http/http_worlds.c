/*
 * http_worlds.c: a cluster node's worlds on one HTTP port (docs/cluster.md).
 * Each world's sim thread adds its status block, hub and base terrain once it
 * has recovered the world and removes them when it stops ticking it; a
 * request takes the world its ?world= names for as long as it runs (a height
 * read waits on the world's sim thread through the hub), so removal waits
 * for the requests in flight — hub_close_reads first makes those fail fast.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "http/http_internal.h"

void http_server_host_worlds(http_server *s)
{
    pthread_mutex_lock(&s->worlds_lock);
    s->hosts_worlds = 1;
    pthread_mutex_unlock(&s->worlds_lock);
}

int http_server_add_world(http_server *s, const char *name, http_status *status, hub *heights,
                          const world *base, error_text *err)
{
    http_world *w = calloc(1, sizeof *w);
    if (!w) {
        error_set(err, "http: out of memory");
        return -1;
    }
    snprintf(w->name, sizeof w->name, "%s", name);
    w->status = status;
    w->heights = heights;
    w->base = base;
    pthread_mutex_lock(&s->worlds_lock);
    int full = s->nworlds >= HTTP_MAX_WORLDS;
    if (!full)
        s->worlds[s->nworlds++] = w;
    pthread_mutex_unlock(&s->worlds_lock);
    if (full) {
        error_set(err, "http: this node already serves %d worlds", HTTP_MAX_WORLDS);
        free(w);
        return -1;
    }
    return 0;
}

void http_server_remove_world(http_server *s, const char *name)
{
    pthread_mutex_lock(&s->worlds_lock);
    for (int i = 0; i < s->nworlds; i++) {
        http_world *w = s->worlds[i];
        if (strcmp(w->name, name) != 0)
            continue;
        /* out of the table first: no new request finds it */
        memmove(&s->worlds[i], &s->worlds[i + 1], (size_t)(s->nworlds - i - 1) * sizeof *s->worlds);
        s->nworlds--;
        while (w->refs > 0)
            pthread_cond_wait(&s->worlds_cond, &s->worlds_lock);
        free(w);
        break;
    }
    pthread_mutex_unlock(&s->worlds_lock);
}

http_world *http_world_acquire(http_server *s, const char *name, unsigned *code, char *why,
                               size_t cap)
{
    pthread_mutex_lock(&s->worlds_lock);
    http_world *found = NULL;
    for (int i = 0; i < s->nworlds && !found; i++)
        if (!name || strcmp(s->worlds[i]->name, name) == 0)
            found = s->worlds[i];
    if (found) {
        found->refs++;
    } else if (!name) {
        *code = MHD_HTTP_SERVICE_UNAVAILABLE;
        snprintf(why, cap, "this node serves no world now (a standby)");
    } else {
        *code = MHD_HTTP_NOT_FOUND;
        size_t n = (size_t)snprintf(why, cap, "this node does not serve world \"%.64s\"", name);
        for (int i = 0; i < s->nworlds && n < cap; i++)
            n += (size_t)snprintf(why + n, cap - n, "%s\"%s\"", i ? ", " : " (it serves ",
                                  s->worlds[i]->name);
        if (n < cap)
            snprintf(why + n, cap - n, "%s; terrad world list names each world's node",
                     s->nworlds ? ")" : "");
    }
    pthread_mutex_unlock(&s->worlds_lock);
    return found;
}

void http_world_release(http_server *s, http_world *w)
{
    pthread_mutex_lock(&s->worlds_lock);
    if (--w->refs == 0)
        pthread_cond_broadcast(&s->worlds_cond);
    pthread_mutex_unlock(&s->worlds_lock);
}
