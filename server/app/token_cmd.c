/*
 * token_cmd.c: `terrad token add | hash` — the auth file's tokens
 * (docs/security.md). `add` makes a fresh random token, appends "ROLE NAME
 * SHA256HEX" to the file (made 0600 when new) and prints the token once, on
 * stdout: the file never holds it. `hash` prints the SHA-256 of a token read
 * from stdin, for tokens made elsewhere. Offline from any tick: a running
 * daemon takes the new line on its next SIGHUP.
 */
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "app/app.h"

#define TOKEN_USAGE "add --auth-file FILE --role viewer|driver|admin --name NAME | hash"

typedef struct token_cmd {
    const char *auth_file, *role, *name;
} token_cmd;

static const cli_option token_options[] = {
    {"auth-file", "FILE", "add: the daemon's --auth-file (made, mode 0600, if missing)",
     CLI_AT_STRING(token_cmd, auth_file)},
    {"role", "ROLE", "add: viewer (subscribe, read), driver (its own colliders) or admin",
     CLI_AT_STRING(token_cmd, role)},
    {"name", "NAME", "add: the token's name in logs (unique in the file; A-Z a-z 0-9 . _ @ -)",
     CLI_AT_STRING(token_cmd, name)},
    {0},
};

void app_token_usage(FILE *out)
{
    cli_print_help(out, "token", TOKEN_USAGE, token_options);
}

/* The file's lines checked as the daemon checks them, and NAME not among them. */
static int check_existing(const char *path, const char *name, error_text *err)
{
    uint8_t *text = NULL;
    size_t len = 0;
    if (access(path, F_OK) != 0)
        return 0; /* a new file */
    if (file_read_all(path, 4u << 20, &text, &len, err) != 0)
        return -1;
    int rc = 0, line_no = 0;
    for (char *line = (char *)text; line && *line && rc == 0;) {
        char *next = strchr(line, '\n');
        if (next)
            *next++ = 0;
        line_no++;
        auth_role role;
        char other[AUTH_NAME_MAX + 1];
        unsigned char hash[32];
        error_text why = {{0}};
        int r = auth_parse_line(line, &role, other, hash, &why);
        if (r < 0)
            error_set(err, "%s: line %d: %s (fix it first)", path, line_no, why.message);
        else if (r == 1 && strcmp(other, name) == 0)
            error_set(err, "%s: line %d already has a token named %s", path, line_no, name);
        rc = r < 0 || (r == 1 && strcmp(other, name) == 0) ? -1 : 0;
        line = next;
    }
    free(text);
    return rc;
}

static int token_add(const token_cmd *c)
{
    if (!c->auth_file || !c->role || !c->name) {
        fprintf(stderr, "terrad token add: --auth-file, --role and --name are required\n");
        return 2;
    }
    auth_role role = auth_role_parse(c->role);
    unsigned char hash[32];
    char line[256], check_name[AUTH_NAME_MAX + 1], hex[65], token[96];
    error_text err = {{0}};
    snprintf(line, sizeof line, "%s %s %064d", c->role, c->name, 0);
    if (role == AUTH_NONE || auth_parse_line(line, &role, check_name, hash, &err) != 1) {
        fprintf(stderr, "terrad token add: %s\n",
                role == AUTH_NONE ? "--role must be viewer, driver or admin" : err.message);
        return 2;
    }
    if (check_existing(c->auth_file, c->name, &err) != 0) {
        fprintf(stderr, "terrad token add: %s\n", err.message);
        return 1;
    }
    if (auth_new_token(token, sizeof token) != 0) {
        fprintf(stderr, "terrad token add: no random bytes from OpenSSL\n");
        return 1;
    }
    auth_hash_hex(token, hex);
    int fd = open(c->auth_file, O_WRONLY | O_APPEND | O_CREAT | O_CLOEXEC, 0600);
    int n = snprintf(line, sizeof line, "%s %s %s\n", auth_role_name(role), c->name, hex);
    if (fd < 0 || write(fd, line, (size_t)n) != n || fsync(fd) != 0) {
        fprintf(stderr, "terrad token add: %s: %s\n", c->auth_file, strerror(errno));
        if (fd >= 0)
            close(fd);
        return 1;
    }
    close(fd);
    printf("%s\n", token);
    fprintf(stderr,
            "terrad token add: %s (role %s) added to %s; the token above is shown only once. "
            "Send SIGHUP to a running daemon to use it.\n",
            c->name, auth_role_name(role), c->auth_file);
    return 0;
}

static int token_hash(void)
{
    char token[1024];
    if (!fgets(token, sizeof token, stdin)) {
        fprintf(stderr, "terrad token hash: give the token on stdin\n");
        return 2;
    }
    token[strcspn(token, "\r\n")] = 0;
    char hex[65];
    auth_hash_hex(token, hex);
    printf("%s\n", hex);
    return 0;
}

/* argv[0] is "token", argv[1] the verb. */
int app_token(int argc, char **argv)
{
    argc--, argv++;
    const char *verb = argc > 0 ? argv[0] : "";
    if (strcmp(verb, "--help") == 0 || strcmp(verb, "-h") == 0) {
        app_token_usage(stdout);
        return 0;
    }
    if (strcmp(verb, "add") != 0 && strcmp(verb, "hash") != 0) {
        fprintf(stderr, "terrad token: expected add or hash (usage: terrad token %s)\n",
                TOKEN_USAGE);
        return 2;
    }
    token_cmd c = {0};
    cli_result parsed = cli_parse("token", TOKEN_USAGE, token_options, argc, argv, &c, NULL);
    if (parsed != CLI_OK)
        return parsed == CLI_HELP ? 0 : 2;
    return strcmp(verb, "add") == 0 ? token_add(&c) : token_hash();
}
