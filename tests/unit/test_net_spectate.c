/*
 * test_net_spectate.c: net_outbox_put (server/net/net_spectate.c), where a
 * spectator's replay thread hands its frames to the net thread. A frame that
 * could not be made (NULL) or kept (no memory to grow the outbox: the same
 * branch, which no test can provoke without starving the process) is dropped
 * and counted in terrad_spectate_frames_dropped_total, and the outbox is left
 * as it was; a frame kept is counted as made (frames and bytes) and its
 * length added to the outbox's bytes. The thread ends its spectate "failed"
 * after a drop (a spectator has no resync): test_spectate runs the rest.
 */
#include <stdlib.h>
#include <string.h>

#include "check.h"
#include "metrics/metrics.h"
#include "net/net_client_internal.h"

/* The value of an unlabelled series in the render (-1: not there). */
static long long series(const char *name)
{
    size_t len = 0;
    char *text = metrics_render(&len);
    long long v = -1;
    size_t n = strlen(name);
    for (const char *p = text; p && (p = strstr(p, name)) != NULL; p++)
        if ((p == text || p[-1] == '\n') && p[n] == ' ') {
            v = strtoll(p + n + 1, NULL, 10);
            break;
        }
    free(text);
    return v;
}

int main(void)
{
    net_outbox box = {0};
    long long dropped = series("terrad_spectate_frames_dropped_total");
    long long frames = series("terrad_spectate_frames_total");
    long long bytes = series("terrad_spectate_bytes_total");
    CHECK(dropped == 0 && frames == 0 && bytes == 0,
          "the spectate counters are rendered, at 0 (dropped %lld, frames %lld, bytes %lld)",
          dropped, frames, bytes);

    hub_frame *f = hub_frame_new(1, 40);
    CHECK(f && net_outbox_put(&box, f) == 0 && box.n == 1 && box.frames[0] == f && box.bytes == 40,
          "a frame kept: 1 frame of 40 bytes in the outbox (%d, %zu bytes)", box.n, box.bytes);
    CHECK(series("terrad_spectate_frames_total") == 1 &&
              series("terrad_spectate_bytes_total") == 40 &&
              series("terrad_spectate_frames_dropped_total") == 0,
          "counted as made, not dropped");

    CHECK(net_outbox_put(&box, NULL) == -1 && box.n == 1 && box.bytes == 40,
          "a frame that could not be made: refused, the outbox as it was (%d, %zu bytes)", box.n,
          box.bytes);
    CHECK(series("terrad_spectate_frames_dropped_total") == 1 &&
              series("terrad_spectate_frames_total") == 1,
          "counted as dropped (%lld), not as made", series("terrad_spectate_frames_dropped_total"));

    for (int i = 0; i < box.n; i++)
        hub_frame_unref(box.frames[i]);
    free(box.frames);
    return check_report();
}
