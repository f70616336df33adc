/*
 * loadgen_http.c: `terrad loadgen`'s plain HTTP/1.0 client for the daemon's own endpoints
 * (GET /v1/stats, /metrics, /v1/heights), and its report (a table or JSON). Blocking and small:
 * it runs only before and after the driving, never inside a tick's wait.
 */
#define _POSIX_C_SOURCE 200809L

#include <netdb.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <unistd.h>

#include "app/http_client_internal.h"
#include "app/loadgen_internal.h"

int lg_http_init(lg_http *h, const char *url, const char *ws_host)
{
    memset(h, 0, sizeof *h);
    if (!url) {
        snprintf(h->host, sizeof h->host, "%s", ws_host);
        h->port = 8080;
        return 0;
    }
    return app_http_url(url, h->host, sizeof h->host, &h->port);
}

/* GET path; the body (malloc'd, NUL after it) and its length. Returns the status or -1.
 * The data endpoints need $TERRAD_TOKEN on a daemon with tokens. */
static int http_get(const lg_http *h, const char *path, char **body, size_t *len)
{
    return app_http_request(h->host, h->port, "GET", path, getenv("TERRAD_TOKEN"), NULL, 0, body,
                            len);
}

static uint64_t json_u64(const char *body, const char *key)
{
    const char *p = strstr(body, key);
    return p ? strtoull(p + strlen(key), NULL, 10) : 0;
}

/* The value of an unlabelled sample "\nNAME VALUE" in a /metrics text, or 0. */
static double metric(const char *body, const char *name)
{
    size_t n = strlen(name);
    for (const char *p = body; (p = strstr(p, name)) != NULL; p += n)
        if ((p == body || p[-1] == '\n') && p[n] == ' ')
            return strtod(p + n + 1, NULL);
    return 0;
}

int lg_http_stats(const lg_http *h, lg_stats *out)
{
    char *body = NULL;
    size_t len = 0;
    if (http_get(h, "/v1/stats", &body, &len) != 200) {
        free(body);
        return -1;
    }
    out->tick = json_u64(body, "\"tick\":");
    out->overruns = json_u64(body, "\"overruns\":");
    free(body);
    body = NULL;
    if (http_get(h, "/metrics", &body, &len) == 200) {
        out->frames_dropped = (uint64_t)metric(body, "terrad_frames_dropped_total");
        out->tick_seconds = metric(body, "terrad_tick_duration_seconds_sum");
        out->tick_count = metric(body, "terrad_tick_duration_seconds_count");
    }
    free(body);
    return 0;
}

int lg_http_heights(const lg_http *h, const char *world, int x, int y, int w, int hh, int32_t *out)
{
    char path[256], *body = NULL;
    size_t len = 0;
    snprintf(path, sizeof path, "/v1/heights?x=%d&y=%d&w=%d&h=%d%s%.80s", x, y, w, hh,
             world[0] ? "&world=" : "", world);
    int status = http_get(h, path, &body, &len);
    int ok = status == 200 && len == (size_t)w * hh * 4;
    if (ok) {
        const unsigned char *b = (const unsigned char *)body;
        for (size_t i = 0; i < len / 4; i++)
            out[i] = (int32_t)((uint32_t)b[4 * i] | (uint32_t)b[4 * i + 1] << 8 |
                               (uint32_t)b[4 * i + 2] << 16 | (uint32_t)b[4 * i + 3] << 24);
    }
    free(body);
    return ok ? 0 : -1;
}

void lg_print_report(FILE *f, const lg_report *r, int json)
{
    double per_tick = r->ticks ? (double)r->delta_bytes / (double)r->ticks : 0;
    double per_cell = r->changed_cells ? (double)r->delta_bytes / (double)r->changed_cells : 0;
    const char *equal = r->mirrors_checked >= 0 && r->mirrors_equal == r->mirrors_checked &&
                                r->mirrors_checked == r->clients
                            ? "true"
                            : "false";
    if (json) {
        fprintf(f,
                "{\"clients\":%ld,\"wheels_per_client\":%ld,\"wheels\":%ld,\"tick_hz\":%g,"
                "\"seconds\":%.3f,\"ticks\":%llu,\"ticks_per_s\":%.2f,\"overruns\":%llu,\"tick_"
                "mean_ms\":%.3f,"
                "\"poses_sent\":%llu,\"latency_ms\":{\"n\":%lld,\"p50\":%.3f,\"p99\":%.3f,"
                "\"max\":%.3f},\"delta_frames\":%llu,\"delta_bytes\":%llu,"
                "\"delta_bytes_per_tick\":%.1f,\"changed_cells\":%llu,"
                "\"delta_bytes_per_changed_cell\":%.3f,\"frames_dropped\":%llu,\"resyncs\":%llu,"
                "\"failed_clients\":%ld,\"mirrors_checked\":%ld,\"mirrors_equal_count\":%ld,"
                "\"mirrors_equal\":%s}\n",
                r->clients, r->wheels_per_client, r->clients * r->wheels_per_client, r->hz,
                r->drive_s, (unsigned long long)r->ticks, r->ticks_per_s,
                (unsigned long long)r->overruns, r->tick_mean_ms, (unsigned long long)r->poses_sent,
                (long long)r->lat_n, r->p50_ms, r->p99_ms, r->max_ms,
                (unsigned long long)r->delta_frames, (unsigned long long)r->delta_bytes, per_tick,
                (unsigned long long)r->changed_cells, per_cell,
                (unsigned long long)r->frames_dropped, (unsigned long long)r->resyncs,
                r->failed_clients, r->mirrors_checked, r->mirrors_equal, equal);
        return;
    }
    fprintf(f, "terrad loadgen: %ld clients x %ld wheels, %.1f s driving at %g Hz\n", r->clients,
            r->wheels_per_client, r->drive_s, r->hz);
    fprintf(f, "  ticks/s reached        %10.2f  (%llu ticks, %llu overruns, mean tick %.2f ms)\n",
            r->ticks_per_s, (unsigned long long)r->ticks, (unsigned long long)r->overruns,
            r->tick_mean_ms);
    fprintf(f, "  pose->ACK latency ms   p50 %.2f  p99 %.2f  max %.2f  (%lld batches)\n", r->p50_ms,
            r->p99_ms, r->max_ms, (long long)r->lat_n);
    fprintf(f, "  delta bytes            %.0f per tick, %.2f per changed cell (%llu frames)\n",
            per_tick, per_cell, (unsigned long long)r->delta_frames);
    fprintf(f, "  frames dropped         %llu (server), resyncs %llu (clients)\n",
            (unsigned long long)r->frames_dropped, (unsigned long long)r->resyncs);
    fprintf(f, "  mirrors equal          %s (%ld of %ld checked, %ld clients; %ld failed)\n", equal,
            r->mirrors_equal, r->mirrors_checked, r->clients, r->failed_clients);
}
