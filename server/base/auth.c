/*
 * auth.c: the token table behind roles (base.h "Authentication"). Read once
 * before the daemon opens a port, again on SIGHUP (from the sim thread's
 * loop, between ticks); checked by the net thread at hello and on every
 * reload, and by the HTTP threads per request. Tokens are never stored:
 * only their SHA-256 (OpenSSL's libcrypto, which libwebsockets' TLS links
 * anyway), compared in constant time.
 */
#include <ctype.h>
#include <errno.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <openssl/crypto.h>
#include <openssl/rand.h>
#include <openssl/sha.h>

#include "base/base.h"

#define AUTH_FILE_MAX_BYTES (4u << 20)

typedef struct auth_entry {
    unsigned char hash[32];
    auth_role role;
    char name[AUTH_NAME_MAX + 1];
    int line; /* in the file, for the repeated-entry message */
} auth_entry;

struct auth_table {
    pthread_rwlock_t lock;
    char *path; /* NULL: no file */
    int enabled;
    auth_entry *entries;
    int count;
    atomic_uint generation;
};

static const char *const role_names[] = {"none", "viewer", "driver", "admin"};

const char *auth_role_name(auth_role r)
{
    return r >= AUTH_NONE && r <= AUTH_ADMIN ? role_names[r] : "none";
}

auth_role auth_role_parse(const char *name)
{
    for (int r = AUTH_VIEWER; r <= AUTH_ADMIN; r++)
        if (strcmp(name, role_names[r]) == 0)
            return (auth_role)r;
    return AUTH_NONE;
}

static void sha256(const char *token, unsigned char out[32])
{
    SHA256((const unsigned char *)token, strlen(token), out);
}

void auth_hash_hex(const char *token, char out[65])
{
    unsigned char h[32];
    sha256(token, h);
    for (int i = 0; i < 32; i++)
        snprintf(out + 2 * i, 3, "%02x", h[i]);
}

int auth_new_token(char *out, size_t cap)
{
    static const char b64url[] = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789-_";
    unsigned char raw[33]; /* 256 bits of entropy, 44 characters, the last one trimmed */
    size_t plen = strlen(AUTH_TOKEN_PREFIX);
    if (cap < plen + 44 + 1 || RAND_bytes(raw, 32) != 1)
        return -1;
    raw[32] = 0;
    memcpy(out, AUTH_TOKEN_PREFIX, plen);
    size_t n = plen;
    for (int i = 0; i < 33; i += 3) {
        unsigned v = (unsigned)raw[i] << 16 | (unsigned)raw[i + 1] << 8 | raw[i + 2];
        for (int k = 3; k >= 0; k--)
            out[n++] = b64url[(v >> (6 * k)) & 63];
    }
    out[plen + 43] = 0; /* 43 characters carry the 256 bits */
    OPENSSL_cleanse(raw, sizeof raw);
    return 0;
}

static int hex_value(int ch)
{
    if (ch >= '0' && ch <= '9')
        return ch - '0';
    if (ch >= 'a' && ch <= 'f')
        return ch - 'a' + 10;
    if (ch >= 'A' && ch <= 'F')
        return ch - 'A' + 10;
    return -1;
}

static int name_ok(const char *s)
{
    size_t n = strlen(s);
    if (n == 0 || n > AUTH_NAME_MAX)
        return 0;
    for (size_t i = 0; i < n; i++)
        if (!isalnum((unsigned char)s[i]) && !strchr("._@-", s[i]))
            return 0;
    return 1;
}

int auth_parse_line(const char *line, auth_role *role, char *name, unsigned char hash[32],
                    error_text *err)
{
    char f[4][160];
    int n = 0;
    const char *p = line;
    while (*p == ' ' || *p == '\t')
        p++;
    if (*p == 0 || *p == '#' || *p == '\n' || *p == '\r')
        return 0;
    while (*p && *p != '\n' && *p != '\r' && n < 4) {
        size_t k = 0;
        while (*p && !isspace((unsigned char)*p))
            if (k + 1 < sizeof f[n])
                f[n][k++] = *p++;
            else
                p++;
        f[n++][k] = 0;
        while (*p == ' ' || *p == '\t')
            p++;
    }
    for (int i = 0; i < n; i++)
        if (strncmp(f[i], AUTH_TOKEN_PREFIX, strlen(AUTH_TOKEN_PREFIX)) == 0) {
            error_set(err, "holds a plain token: the file keeps only its SHA-256 (64 hex digits; "
                           "`terrad token hash` prints it)");
            return -1;
        }
    if (n != 3 || (*p && *p != '\n' && *p != '\r')) {
        error_set(err, "expected three fields \"ROLE NAME SHA256HEX\", found %s",
                  n < 3 ? "fewer" : "more");
        return -1;
    }
    *role = auth_role_parse(f[0]);
    if (*role == AUTH_NONE) {
        error_set(err, "unknown role \"%.40s\" (viewer, driver or admin)", f[0]);
        return -1;
    }
    if (!name_ok(f[1])) {
        error_set(err, "the name must be 1..%d of A-Z a-z 0-9 . _ @ -", AUTH_NAME_MAX);
        return -1;
    }
    size_t name_len = strlen(f[1]); /* name_ok: at most AUTH_NAME_MAX */
    memcpy(name, f[1], name_len + 1);
    int hex = strlen(f[2]) == 64;
    for (int i = 0; hex && i < 32; i++) {
        int hi = hex_value(f[2][2 * i]), lo = hex_value(f[2][2 * i + 1]);
        hex = hi >= 0 && lo >= 0;
        if (hex)
            hash[i] = (unsigned char)(hi << 4 | lo);
    }
    if (!hex) {
        error_set(err, "the third field is not a SHA-256 (64 hex digits); a plain token? the file "
                       "keeps only hashes (`terrad token hash`)");
        return -1;
    }
    return 1;
}

static int by_name(const void *a, const void *b)
{
    const auth_entry *x = *(const auth_entry *const *)a, *y = *(const auth_entry *const *)b;
    int c = strcmp(x->name, y->name);
    return c ? c : x->line - y->line;
}

static int by_hash(const void *a, const void *b)
{
    const auth_entry *x = *(const auth_entry *const *)a, *y = *(const auth_entry *const *)b;
    int c = memcmp(x->hash, y->hash, 32);
    return c ? c : x->line - y->line;
}

/* A name or hash given twice (sorted, so a reload of thousands of lines stays
 * well inside a tick): -1 with err naming the later line. */
static int check_repeats(const char *path, auth_entry *e, int n, error_text *err)
{
    if (n < 2)
        return 0;
    const auth_entry **p = malloc((size_t)n * sizeof *p);
    if (!p) {
        error_set(err, "%s: out of memory", path);
        return -1;
    }
    int rc = 0;
    for (int pass = 0; pass < 2 && rc == 0; pass++) {
        for (int i = 0; i < n; i++)
            p[i] = &e[i];
        qsort(p, (size_t)n, sizeof *p, pass == 0 ? by_name : by_hash);
        for (int i = 1; i < n && rc == 0; i++)
            if (pass == 0 ? strcmp(p[i - 1]->name, p[i]->name) == 0
                          : memcmp(p[i - 1]->hash, p[i]->hash, 32) == 0) {
                error_set(err, "%s: line %d: token %s repeats line %d's %s", path, p[i]->line,
                          p[i]->name, p[i - 1]->line, pass == 0 ? "name" : "hash");
                rc = -1;
            }
    }
    free(p);
    return rc;
}

/* The file's entries into *out (malloc'd), or -1 with err naming file and line. */
static int read_file(const char *path, auth_entry **out, int *count, error_text *err)
{
    uint8_t *text = NULL;
    size_t len = 0;
    *out = NULL;
    *count = 0;
    if (file_read_all(path, AUTH_FILE_MAX_BYTES, &text, &len, err) != 0)
        return -1;
    int cap = 0, n = 0, line_no = 0, rc = 0;
    auth_entry *e = NULL;
    for (char *line = (char *)text; line && *line && rc == 0;) {
        char *next = strchr(line, '\n');
        if (next)
            *next++ = 0;
        line_no++;
        auth_entry a;
        error_text why = {{0}};
        int r = auth_parse_line(line, &a.role, a.name, a.hash, &why);
        a.line = line_no;
        if (r < 0) {
            error_set(err, "%s: line %d: %s", path, line_no, why.message);
            rc = -1;
        } else if (r == 1) {
            if (n == cap) {
                cap = cap ? 2 * cap : 16;
                auth_entry *g = realloc(e, (size_t)cap * sizeof *e);
                if (!g) {
                    error_set(err, "%s: out of memory", path);
                    rc = -1;
                    break;
                }
                e = g;
            }
            e[n++] = a;
        }
        line = next;
    }
    OPENSSL_cleanse(text, len);
    free(text);
    if (rc == 0)
        rc = check_repeats(path, e, n, err);
    if (rc != 0) {
        free(e);
        return -1;
    }
    *out = e;
    *count = n;
    return 0;
}

auth_table *auth_create(const char *path, error_text *err)
{
    auth_table *t = calloc(1, sizeof *t);
    if (!t) {
        error_set(err, "auth: out of memory");
        return NULL;
    }
    pthread_rwlock_init(&t->lock, NULL);
    if (path && path[0]) {
        t->path = strdup(path);
        t->enabled = 1;
        if (!t->path || read_file(path, &t->entries, &t->count, err) != 0) {
            if (!t->path)
                error_set(err, "auth: out of memory");
            auth_free(t);
            return NULL;
        }
    }
    return t;
}

void auth_free(auth_table *t)
{
    if (!t)
        return;
    free(t->entries);
    free(t->path);
    pthread_rwlock_destroy(&t->lock);
    free(t);
}

int auth_reload(auth_table *t, error_text *err)
{
    if (!t->path) {
        error_set(err, "no auth file to read again");
        return -1;
    }
    auth_entry *e;
    int n;
    if (read_file(t->path, &e, &n, err) != 0)
        return -1;
    pthread_rwlock_wrlock(&t->lock);
    auth_entry *old = t->entries;
    t->entries = e;
    t->count = n;
    atomic_fetch_add(&t->generation, 1);
    pthread_rwlock_unlock(&t->lock);
    free(old);
    return 0;
}

int auth_enabled(const auth_table *t)
{
    return t && t->enabled;
}

int auth_count(const auth_table *t)
{
    return t ? t->count : 0;
}

unsigned auth_generation(const auth_table *t)
{
    return t ? atomic_load(&((auth_table *)t)->generation) : 0;
}

/* Under the read lock: every entry is compared, so the time does not say which matched. */
static auth_role lookup(auth_table *t, const unsigned char h[32], char *name, size_t cap)
{
    auth_role role = AUTH_NONE;
    const char *who = NULL;
    for (int i = 0; i < t->count; i++)
        if (CRYPTO_memcmp(h, t->entries[i].hash, 32) == 0 && role == AUTH_NONE) {
            role = t->entries[i].role;
            who = t->entries[i].name;
        }
    if (name && cap)
        snprintf(name, cap, "%s", who ? who : "");
    return role;
}

auth_role auth_check(auth_table *t, const char *token, char *name, size_t name_cap,
                     unsigned char hash[32])
{
    unsigned char h[32];
    sha256(token ? token : "", h);
    if (hash)
        memcpy(hash, h, 32);
    if (!auth_enabled(t)) {
        if (name && name_cap)
            snprintf(name, name_cap, "%s", "");
        return AUTH_ADMIN;
    }
    pthread_rwlock_rdlock(&t->lock);
    auth_role r = lookup(t, h, name, name_cap);
    pthread_rwlock_unlock(&t->lock);
    return r;
}

auth_role auth_role_of_hash(auth_table *t, const unsigned char hash[32])
{
    if (!auth_enabled(t))
        return AUTH_ADMIN;
    pthread_rwlock_rdlock(&t->lock);
    auth_role r = lookup(t, hash, NULL, 0);
    pthread_rwlock_unlock(&t->lock);
    return r;
}
