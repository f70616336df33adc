/*
 * fsck.c: `terrad fsck --data DIR` — checks a data directory the way a start
 * would (manifest against the scene, CONTROL, every tile snapshot, every log
 * segment and record) without changing anything, and logs every damage it
 * finds with the file it is in (store_fsck). Exit 0: clean (a torn tail of
 * the newest segment, which a start cuts, is only reported); 1: damaged, a
 * start would be refused; 2: a usage error. Run it on a stopped daemon's
 * directory: a live one may be compacting under it.
 */
#include <stdio.h>
#include <string.h>

#include "app/app.h"
#include "store/store.h"
#include "world/world.h"

typedef struct fsck_options {
    const char *data, *scene_path;
} fsck_options;

static const cli_option fsck_table[] = {
    {"data", "DIR", "data directory to check (default ./data); never changed",
     CLI_AT_STRING(fsck_options, data)},
    APP_OPTION_SCENE_RAN(fsck_options, scene_path),
    {0},
};

static const char fsck_usage[] = "[--data DIR] [--scene FILE]";

void app_fsck_usage(FILE *out)
{
    cli_print_help(out, "fsck", fsck_usage, fsck_table);
}

/* Every damage the directory has, logged; 0 clean, 1 damaged. */
static int fsck_run(void *ctx, world *w)
{
    const fsck_options *o = ctx;
    error_text err = {{0}};
    store_recovery rec;
    int rc = store_fsck(o->data, w, &rec, &err);
    if (rc == 0)
        log_info("fsck: %s is clean: tick %llu from %d tile snapshots and %lld log records%s",
                 o->data, (unsigned long long)rec.tick, rec.tiles_loaded,
                 (long long)rec.records_replayed,
                 rec.bytes_cut ? " (a torn tail, which a start cuts)" : "");
    else
        log_error("fsck: %s is damaged (%d problems); first: %s", o->data,
                  rec.damage > 0 ? rec.damage : 1, err.message);
    return rc == 0 ? 0 : 1;
}

int app_fsck(int argc, char **argv)
{
    fsck_options o = {.data = "./data"};
    cli_result parsed = cli_parse("fsck", fsck_usage, fsck_table, argc, argv, &o, NULL);
    if (parsed != CLI_OK)
        return parsed == CLI_HELP ? 0 : 2;
    return app_offline_world(o.scene_path, fsck_run, &o);
}
