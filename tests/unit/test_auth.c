// ctest-timeout: 60
/*
 * test_auth.c: the token table (server/base/auth.c) and the TLS pair check
 * (server/base/tls.c) on their own: the auth file's line format and every
 * refusal it names, SHA-256 against the FIPS 180-2 vector, fresh tokens,
 * roles by token and by hash, the deprecated single token as an admin, a
 * reload that revokes (generation bumped) and one that fails (old tokens
 * kept), and tls_check_pair on missing files. Real files in a temporary
 * directory.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "base/base.h"
#include "check.h"

static char dir[] = "/tmp/test_auth.XXXXXX";

static void write_file(const char *path, const char *text)
{
    FILE *f = fopen(path, "w");
    if (f) {
        fputs(text, f);
        fclose(f);
    }
}

static void test_lines(void)
{
    auth_role r;
    char name[AUTH_NAME_MAX + 1];
    unsigned char h[32];
    error_text e = {{0}};
    CHECK(auth_parse_line("  # a comment", &r, name, h, &e) == 0, "a comment is no entry");
    CHECK(auth_parse_line("", &r, name, h, &e) == 0, "a blank line is no entry");
    char line[160];
    snprintf(line, sizeof line, "driver car-7 %s",
             "ab"
             "cdef0123456789ab"
             "cdef0123456789ab"
             "cdef0123456789ab"
             "cdef0123456789");
    CHECK(auth_parse_line(line, &r, name, h, &e) == 1 && r == AUTH_DRIVER &&
              strcmp(name, "car-7") == 0 && h[0] == 0xab && h[31] == 0x89,
          "a good line: %s", e.message);
    CHECK(auth_parse_line("viewer v tdk_abc", &r, name, h, &e) < 0 &&
              strstr(e.message, "plain token"),
          "a plain token is named as such: %s", e.message);
    CHECK(auth_parse_line("viewer v deadbeef", &r, name, h, &e) < 0 && strstr(e.message, "SHA-256"),
          "a short hash: %s", e.message);
    CHECK(auth_parse_line("root v "
                          "00000000000000000000000000000000"
                          "00000000000000000000000000000000",
                          &r, name, h, &e) < 0 &&
              strstr(e.message, "unknown role"),
          "an unknown role: %s", e.message);
    CHECK(auth_parse_line("viewer v", &r, name, h, &e) < 0 && strstr(e.message, "three fields"),
          "two fields: %s", e.message);
    CHECK(auth_parse_line("viewer bad/name "
                          "00000000000000000000000000000000"
                          "00000000000000000000000000000000",
                          &r, name, h, &e) < 0,
          "a name with '/' is refused");
}

static void test_hash_and_tokens(void)
{
    char hex[65];
    auth_hash_hex("abc", hex);
    CHECK(strcmp(hex, "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad") == 0,
          "SHA-256(\"abc\") is the FIPS 180-2 vector: %s", hex);
    char a[96], b[96];
    CHECK(auth_new_token(a, sizeof a) == 0 && auth_new_token(b, sizeof b) == 0, "tokens made");
    CHECK(strncmp(a, AUTH_TOKEN_PREFIX, 4) == 0 && strlen(a) == 47 && strcmp(a, b) != 0,
          "a token is tdk_ + 43 characters, fresh each time: %s", a);
    CHECK(auth_new_token(a, 20) < 0, "a buffer too small is refused");
}

static void test_table(void)
{
    char path[256], line[512], hex_v[65], hex_d[65];
    snprintf(path, sizeof path, "%s/tokens", dir);
    auth_hash_hex("viewer-secret", hex_v);
    auth_hash_hex("driver-secret", hex_d);
    snprintf(line, sizeof line, "# tokens\nviewer eye %s\ndriver car %s\n", hex_v, hex_d);
    write_file(path, line);
    error_text e = {{0}};
    auth_table *t = auth_create(path, &e);
    CHECK(t != NULL, "the file is read: %s", e.message);
    if (!t)
        return;
    char name[AUTH_NAME_MAX + 1];
    unsigned char hash[32];
    CHECK(auth_enabled(t) && auth_count(t) == 2, "two tokens");
    CHECK(auth_check(t, "viewer-secret", name, sizeof name, hash) == AUTH_VIEWER &&
              strcmp(name, "eye") == 0,
          "a viewer token");
    CHECK(auth_check(t, "driver-secret", NULL, 0, NULL) == AUTH_DRIVER, "a driver token");
    CHECK(auth_check(t, "nope", NULL, 0, NULL) == AUTH_NONE &&
              auth_check(t, "", NULL, 0, NULL) == AUTH_NONE,
          "unknown and empty tokens are refused");
    unsigned gen = auth_generation(t);

    snprintf(line, sizeof line, "driver car %s\n", hex_d); /* the viewer revoked */
    write_file(path, line);
    CHECK(auth_reload(t, &e) == 0 && auth_generation(t) == gen + 1, "reload: %s", e.message);
    CHECK(auth_role_of_hash(t, hash) == AUTH_NONE, "the viewer's hash is revoked");
    CHECK(auth_check(t, "driver-secret", NULL, 0, NULL) == AUTH_DRIVER, "the driver stays");

    write_file(path, "driver car\n");
    CHECK(auth_reload(t, &e) < 0 && strstr(e.message, "line 1") && strstr(e.message, path),
          "a bad reload names the file and line: %s", e.message);
    CHECK(auth_generation(t) == gen + 1 &&
              auth_check(t, "driver-secret", NULL, 0, NULL) == AUTH_DRIVER,
          "a bad reload keeps the old tokens");
    auth_free(t);

    snprintf(line, sizeof line, "viewer a %s\ndriver a %s\n", hex_v, hex_d);
    write_file(path, line);
    CHECK(auth_create(path, &e) == NULL && strstr(e.message, "line 2"), "a repeated name: %s",
          e.message);
    snprintf(line, sizeof line, "%s/none", dir);
    CHECK(auth_create(line, &e) == NULL && strstr(e.message, line), "a missing file: %s",
          e.message);
    auth_table *off = auth_create(NULL, &e);
    CHECK(off && !auth_enabled(off) && auth_check(off, "", NULL, 0, NULL) == AUTH_ADMIN,
          "no file, no token: auth off, every client an admin");
    auth_free(off);
    unlink(path);
}

static void test_tls_files(void)
{
    error_text e = {{0}};
    char cert[256];
    snprintf(cert, sizeof cert, "%s/none.crt", dir);
    CHECK(tls_check_pair(cert, cert, &e) < 0 && strstr(e.message, cert), "a missing cert: %s",
          e.message);
    CHECK(tls_check_pair(cert, NULL, &e) < 0 && strstr(e.message, "--tls-key"),
          "a cert without a key: %s", e.message);
}

int main(void)
{
    if (!mkdtemp(dir)) {
        printf("cannot make a temporary directory\n");
        return 1;
    }
    test_lines();
    test_hash_and_tokens();
    test_table();
    test_tls_files();
    rmdir(dir);
    return check_report();
}
