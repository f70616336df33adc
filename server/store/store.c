/*
 * store.c: the store's one face (store.h) over its backend (store_internal.h).
 * Each call checks that it comes from the store's sim thread — the thread
 * that opened it, which then runs the tick loop — and hands over to the
 * backend's table. Also here: the durability policy's names and CRC32C, which
 * every backend's format uses.
 */
#include "store/store.h"

#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "store/store_internal.h"

struct store {
    const store_backend *backend;
    void *state;
    thread_owner sim; /* the thread that opened the store: the sim thread */
};

store *store_open(const store_config *c, world *w, store_recovery *rec, error_text *err)
{
    store *st = calloc(1, sizeof *st);
    if (!st) {
        error_set(err, "store: out of memory");
        return NULL;
    }
    st->backend = &store_backend_dir;
    st->state = st->backend->open(c, w, rec, err);
    if (!st->state) {
        free(st);
        return NULL;
    }
    thread_owner_claim(&st->sim, "sim");
    return st;
}

void store_claim(store *st)
{
    thread_owner_claim(&st->sim, "sim");
}

store *store_adopt(const store_backend *backend, void *state)
{
    store *st = calloc(1, sizeof *st);
    if (!st)
        return NULL;
    st->backend = backend;
    st->state = state;
    thread_owner_claim(&st->sim, "sim");
    return st;
}

void store_close(store *st)
{
    if (!st)
        return;
    THREAD_OWNED(&st->sim);
    st->backend->close(st->state);
    free(st);
}

int store_writable(store *st)
{
    THREAD_OWNED(&st->sim);
    return st->backend->writable(st->state);
}

const char *store_failure(const store *st)
{
    THREAD_OWNED(&st->sim);
    return st->backend->failure(st->state);
}

int store_commit_tick(store *st, const world *w, uint64_t tick, const world_rect *rects, int n)
{
    THREAD_OWNED(&st->sim);
    return st->backend->append_tick(st->state, w, tick, rects, n);
}

int store_settle(store *st)
{
    THREAD_OWNED(&st->sim);
    return st->backend->settle(st->state);
}

uint64_t store_durable_tick(const store *st)
{
    THREAD_OWNED(&st->sim);
    return st->backend->durable_tick(st->state);
}

/* ---- the durability policy ---- */

int store_parse_durability(const char *text, store_config *c, error_text *err)
{
    if (strcmp(text, "every-tick") == 0) {
        c->durability = STORE_EVERY_TICK;
        return 0;
    }
    if (strcmp(text, "none") == 0) {
        c->durability = STORE_NONE;
        return 0;
    }
    if (strncmp(text, "group:", 6) == 0) {
        char *end;
        long ms = strtol(text + 6, &end, 10);
        if (text[6] && !*end && ms >= 1 && ms <= 10000) {
            c->durability = STORE_GROUP;
            c->group_ms = (int)ms;
            return 0;
        }
    }
    error_set(err, "durability: \"%s\" is not every-tick, none or group:MS (MS in 1..10000)", text);
    return -1;
}

const char *store_durability_name(const store_config *c, char *buf, size_t cap)
{
    if (c->durability == STORE_GROUP)
        snprintf(buf, cap, "group:%d", c->group_ms);
    else
        snprintf(buf, cap, "%s", c->durability == STORE_NONE ? "none" : "every-tick");
    return buf;
}

/* ---- CRC32C (Castagnoli, reflected 0x82F63B78), table driven ---- */

static uint32_t crc_table[256];
static pthread_once_t crc_once = PTHREAD_ONCE_INIT;

static void crc_init(void)
{
    for (uint32_t i = 0; i < 256; i++) {
        uint32_t c = i;
        for (int k = 0; k < 8; k++)
            c = c & 1 ? (c >> 1) ^ 0x82F63B78u : c >> 1;
        crc_table[i] = c;
    }
}

uint32_t store_crc32c(uint32_t crc, const void *data, size_t len)
{
    pthread_once(&crc_once, crc_init);
    const uint8_t *p = data;
    crc = ~crc;
    while (len--)
        crc = crc_table[(crc ^ *p++) & 0xff] ^ (crc >> 8);
    return ~crc;
}

int store_file_read(const char *path, const char *what, uint8_t **data, size_t *len,
                    error_text *err)
{
    error_text read_err = {{0}};
    *data = NULL;
    *len = 0;
    if (file_read_all(path, STORE_FILE_BYTES_MAX, data, len, &read_err) == 0)
        return 0;
    error_set(err, "store: cannot read %s%s", what, read_err.message);
    return -1;
}

const char *store_text_crc_end(const char *text, const char *tail)
{
    char marker[16];
    snprintf(marker, sizeof marker, "%scrc32c ", tail);
    const char *at = strstr(text, marker);
    if (!at)
        return NULL;
    const char *end = at + strlen(tail);
    unsigned stored = 0;
    if (sscanf(end, "crc32c %8x", &stored) != 1 ||
        store_crc32c(0, text, (size_t)(end - text)) != stored)
        return NULL;
    return end;
}
