/*
 * test_metrics.c: the Prometheus exposition of server/metrics — counts land
 * in the right series, histograms are cumulative and in seconds, Σh is exact
 * above 2^53, label values are escaped, and (when Debian's promtool is
 * installed) `promtool check metrics` accepts the whole render.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "metrics/metrics.h"
#include "terrad_proto.h"
#include "check.h"

/* 1 if the render has this exact line. */
static int has_line(const char *text, const char *line)
{
    size_t n = strlen(line);
    for (const char *p = text; (p = strstr(p, line)) != NULL; p++)
        if ((p == text || p[-1] == '\n') && (p[n] == '\n' || p[n] == '\0'))
            return 1;
    return 0;
}

static void expect_line(const char *text, const char *line)
{
    CHECK(has_line(text, line), "missing line: %s", line);
}

/* Every sample's metric family has HELP and TYPE lines before it. */
static void check_metadata(const char *text)
{
    int samples = 0, orphans = 0;
    const char *p = text;
    while (*p) {
        const char *end = strchr(p, '\n');
        size_t n = end ? (size_t)(end - p) : strlen(p);
        if (n && p[0] != '#') {
            char name[128];
            size_t k = 0;
            while (k < n && k + 1 < sizeof name && p[k] != '{' && p[k] != ' ') {
                name[k] = p[k];
                k++;
            }
            name[k] = '\0';
            /* Histogram samples belong to the family without the suffix. */
            const char *suffixes[] = {"_bucket", "_sum", "_count"};
            char help[200], type[200];
            int found = 0;
            for (int s = -1; s < 3 && !found; s++) {
                char family[128];
                snprintf(family, sizeof family, "%s", name);
                if (s >= 0) {
                    size_t fl = strlen(family), sl = strlen(suffixes[s]);
                    if (fl <= sl || strcmp(family + fl - sl, suffixes[s]) != 0)
                        continue;
                    family[fl - sl] = '\0';
                }
                snprintf(help, sizeof help, "# HELP %s ", family);
                snprintf(type, sizeof type, "# TYPE %s ", family);
                found = strstr(text, help) && strstr(text, type);
            }
            samples++;
            if (!found) {
                orphans++;
                printf("no HELP/TYPE for %s\n", name);
            }
        }
        p += n + (end ? 1 : 0);
    }
    CHECK(samples > 50, "render has %d samples", samples);
    CHECK(orphans == 0, "%d samples without HELP/TYPE", orphans);
}

static void run_promtool(const char *text, size_t len)
{
    if (access("/usr/bin/promtool", X_OK) != 0) {
        printf("skip: /usr/bin/promtool not installed, promtool check not run\n");
        return;
    }
    char path[] = "/tmp/test_metrics_XXXXXX";
    int fd = mkstemp(path);
    CHECK(fd >= 0, "mkstemp");
    if (fd < 0)
        return;
    CHECK(write(fd, text, len) == (ssize_t)len, "write render");
    close(fd);
    char cmd[256];
    snprintf(cmd, sizeof cmd, "/usr/bin/promtool check metrics < %s", path);
    int rc = system(cmd);
    CHECK(rc == 0, "promtool check metrics exit status %d (render in %s)", rc, path);
    if (rc == 0)
        unlink(path);
}

int main(void)
{
    metrics_reset();

    /* An empty render is already valid. */
    size_t len = 0;
    char *text = metrics_render(&len);
    CHECK(text && len == strlen(text), "render of fresh metrics");
    expect_line(text, "terrad_delta_compression_ratio 0");
    expect_line(text, "terrad_tick_duration_seconds_count 0");
    expect_line(text, "# TYPE terrad_memory_bytes gauge");
    run_promtool(text, len);
    free(text);

    metrics_count_bytes_in(100);
    metrics_count_bytes_in(23);
    metrics_count_bytes_out(5000);
    metrics_count_messages_in(7);
    metrics_count_frames_out(9);
    metrics_count_frames_coalesced(2);
    metrics_count_frames_dropped(3);
    metrics_count_tick_overrun();
    metrics_count_tick_overrun();
    metrics_count_refused_windows(4);
    metrics_count_delta_bytes(4000, 1000);
    metrics_count_delta_bytes(2000, 1000);
    metrics_count_refused(TERRAD_ERR_FIRST);
    metrics_count_refused(TERRAD_ERR_FIRST);
    metrics_count_refused(9999); /* unknown → internal */
    metrics_count_refused(-5);   /* unknown → internal */
    metrics_count_refused(TERRAD_E_INTERNAL);

    metrics_observe_tick_ms(0.25);      /* ≤ 0.5 ms */
    metrics_observe_tick_ms(3.0);       /* ≤ 4 ms */
    metrics_observe_tick_ms(16.0);      /* ≤ 16 ms: bounds are inclusive */
    metrics_observe_tick_ms(500);       /* +Inf only */
    metrics_observe_tick_ms(0.0 / 0.0); /* NaN: ignored */
    metrics_observe_tick_ms(-1);        /* ignored */
    metrics_observe_stage_ms("depth", 0.2);
    metrics_observe_stage_ms("gather_scatter", 40);
    metrics_observe_stage_ms("no_such_stage", 1); /* dropped */
    metrics_observe_pose_to_delta_ms(20);
    metrics_set_stage_memory_bytes("jump_flood", 4096);
    metrics_set_stage_memory_bytes("model", 77);
    metrics_set_stage_memory_bytes("no_such_stage_bytes", 5); /* dropped */

    metrics_set_tick(123456);
    /* 2^53 + 1: a double would print 9007199254740992. */
    metrics_set_volume(9007199254740993LL);
    metrics_set_active_cells(4096);
    metrics_set_colliders(5);
    metrics_set_clients(3);
    metrics_set_memory_bytes("world_heights", 1048576);
    metrics_set_memory_bytes("sim_scratch", 10);
    metrics_set_memory_bytes("sim_scratch", 20); /* replaces */
    metrics_set_memory_bytes("we\"ird\\part\nname", 5);
    metrics_count_service_dropped("frame");
    metrics_count_service_dropped("frame");
    metrics_count_service_dropped("snapshot");
    metrics_count_service_dropped("no_such_reason"); /* dropped */
    metrics_count_cluster_take_redone();
    metrics_count_cluster_take_redone();

    text = metrics_render(&len);
    CHECK(text != NULL, "render");
    if (!text)
        return 1;
    expect_line(text, "terrad_bytes_in_total 123");
    expect_line(text, "terrad_bytes_out_total 5000");
    expect_line(text, "terrad_messages_in_total 7");
    expect_line(text, "terrad_frames_out_total 9");
    expect_line(text, "terrad_frames_coalesced_total 2");
    expect_line(text, "terrad_frames_dropped_total 3");
    expect_line(text, "terrad_tick_overruns_total 2");
    expect_line(text, "terrad_refused_windows_total 4");
    expect_line(text, "terrad_delta_raw_bytes_total 6000");
    expect_line(text, "terrad_delta_compressed_bytes_total 2000");
    expect_line(text, "terrad_delta_compression_ratio 3");
    expect_line(text, "# TYPE terrad_delta_compression_ratio gauge");
    expect_line(text, "# TYPE terrad_service_dropped_total counter");
    expect_line(text, "terrad_service_dropped_total{reason=\"frame\"} 2");
    expect_line(text, "terrad_cluster_takes_redone_total 2");
    expect_line(text, "# TYPE terrad_cluster_takes_redone_total counter");
    expect_line(text, "terrad_service_dropped_total{reason=\"snapshot\"} 1");
    expect_line(text, "terrad_service_dropped_total{reason=\"poses\"} 0");

    char line[160];
    snprintf(line, sizeof line, "terrad_refused_messages_total{reason=\"%s\"} 2",
             terrad_err_name(TERRAD_ERR_FIRST));
    expect_line(text, line);
    expect_line(text, "terrad_refused_messages_total{reason=\"internal\"} 3");
    int reasons = 0;
    for (const char *p = text; (p = strstr(p, "\nterrad_refused_messages_total{")); p++)
        reasons++;
    CHECK(reasons == TERRAD_ERR_LAST, "one refused series per wire error (%d)", reasons);
    expect_line(text, "# TYPE terrad_refused_messages_total counter");

    expect_line(text, "# TYPE terrad_tick_duration_seconds histogram");
    expect_line(text, "terrad_tick_duration_seconds_bucket{le=\"0.0005\"} 1");
    expect_line(text, "terrad_tick_duration_seconds_bucket{le=\"0.002\"} 1");
    expect_line(text, "terrad_tick_duration_seconds_bucket{le=\"0.004\"} 2");
    expect_line(text, "terrad_tick_duration_seconds_bucket{le=\"0.016\"} 3");
    expect_line(text, "terrad_tick_duration_seconds_bucket{le=\"0.133\"} 3");
    expect_line(text, "terrad_tick_duration_seconds_bucket{le=\"+Inf\"} 4");
    expect_line(text, "terrad_tick_duration_seconds_count 4");
    expect_line(text, "terrad_tick_duration_seconds_sum 0.51925");

    expect_line(text, "# TYPE terrad_stage_duration_seconds histogram");
    expect_line(text, "terrad_stage_duration_seconds_bucket{stage=\"depth\",le=\"0.00025\"} 1");
    expect_line(text, "terrad_stage_duration_seconds_count{stage=\"depth\"} 1");
    expect_line(text, "terrad_stage_duration_seconds_count{stage=\"gather_scatter\"} 1");
    expect_line(text,
                "terrad_stage_duration_seconds_bucket{stage=\"gather_scatter\",le=\"+Inf\"} 1");
    expect_line(text,
                "terrad_stage_duration_seconds_bucket{stage=\"gather_scatter\",le=\"0.033\"} 0");
    expect_line(text, "terrad_stage_duration_seconds_count{stage=\"jump_flood\"} 0");
    CHECK(!strstr(text, "no_such_stage"), "unknown stage names are not rendered");
    expect_line(text, "# TYPE terrad_sim_scratch_bytes gauge");
    expect_line(text, "terrad_sim_scratch_bytes{stage=\"jump_flood\"} 4096");
    expect_line(text, "terrad_sim_scratch_bytes{stage=\"model\"} 77");
    expect_line(text, "terrad_sim_scratch_bytes{stage=\"displace\"} 0");
    expect_line(text, "terrad_pose_to_delta_latency_seconds_bucket{le=\"0.033\"} 1");
    expect_line(text, "terrad_pose_to_delta_latency_seconds_bucket{le=\"0.017\"} 0");

    expect_line(text, "terrad_tick 123456");
    expect_line(text, "terrad_volume_units 9007199254740993");
    expect_line(text, "terrad_active_cells 4096");
    expect_line(text, "terrad_colliders 5");
    expect_line(text, "terrad_clients 3");
    expect_line(text, "terrad_memory_bytes{part=\"world_heights\"} 1048576");
    expect_line(text, "terrad_memory_bytes{part=\"sim_scratch\"} 20");
    expect_line(text, "terrad_memory_bytes{part=\"we\\\"ird\\\\part\\nname\"} 5");
    CHECK(!strstr(text, "sim_scratch\"} 10"), "a part's bytes are replaced, not added");

    check_metadata(text);
    run_promtool(text, len);
    free(text);

    /* Negative Σh is still exact. */
    metrics_set_volume(-9007199254740993LL);
    text = metrics_render(&len);
    expect_line(text, "terrad_volume_units -9007199254740993");
    free(text);

    /* At most 32 memory parts; the rest are ignored, not grown into. */
    metrics_reset();
    for (int i = 0; i < 40; i++) {
        char name[16];
        snprintf(name, sizeof name, "part%d", i);
        metrics_set_memory_bytes(name, (uint64_t)i);
    }
    text = metrics_render(&len);
    expect_line(text, "terrad_memory_bytes{part=\"part31\"} 31");
    CHECK(!strstr(text, "part32"), "33rd part ignored");
    expect_line(text, "terrad_bytes_in_total 0");
    expect_line(text, "terrad_cluster_takes_redone_total 0");
    free(text);

    printf("%d passed, %d failed\n", passed, failed);
    return failed ? 1 : 0;
}
