// ctest-timeout: 60
/*
 * test_cli.c: the one command-line parser (server/base/cli.c) on its own
 * table: each way a row stores its value (a string, a long, an int, a
 * double in [lo, hi], a flag, a row's call, a call given an integer in
 * [lo, hi]), "--opt value" and "--opt=value", operands, every refusal
 * exactly as the commands print it ("terrad CMD: --name: <why>", the field
 * left as it was), and --help showing each numeric row's range from the row
 * itself (no help text writes it). The commands' own tables are held to
 * their --help and messages by the integration tests.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "base/base.h"
#include "check.h"

typedef struct opts {
    const char *name;
    long count;
    int port;
    double ratio;
    int verbose;
    struct {
        double depth;
    } inner;
    int calls;
    const char *called_with;
    long bytes, ticks, hz;
} opts;

static int pick_option(void *ctx, const char *value, error_text *err)
{
    opts *o = ctx;
    o->calls++;
    o->called_with = value;
    if (value && strcmp(value, "bad") == 0) {
        error_set(err, "\"%s\" is not a pick", value);
        return -1;
    }
    return 0;
}

/* a call whose row checked the range: the value is a whole number in it */
static int hz_option(void *ctx, const char *value, error_text *err)
{
    (void)err;
    ((opts *)ctx)->hz = strtol(value, NULL, 10);
    return 0;
}

static const cli_option table[] = {
    {"name", "S", "a string", CLI_AT_STRING(opts, name)},
    {"count", "N", "a long", CLI_AT_LONG(opts, count, 0, 50)},
    {"port", "N", "an int\nsecond line", CLI_AT_INT(opts, port, 0, 65535)},
    {"ratio", "X", "a double", CLI_AT_DOUBLE(opts, ratio, 0, 1)},
    {"depth", "M", "a nested double", CLI_AT_DOUBLE(opts, inner.depth, 1e-3, 10)},
    {"verbose", NULL, "a flag", CLI_AT_FLAG(opts, verbose)},
    {"pick", "P", "a call", CLI_CALLS(pick_option)},
    {"a-long-option-name-here", NULL, "wraps", CLI_CALLS(pick_option)},
    {"bytes", "N", "a large power of two", CLI_AT_LONG(opts, bytes, 4096, 1L << 40)},
    {"ticks", "N", "a last line too long for its range to follow it on the same line",
     CLI_AT_LONG(opts, ticks, 0, 100000000)},
    {"hz", "N", "a call given an integer", CLI_CALLS_LONG(hz_option, 1, 1000)},
    {0},
};

/* cli_parse on a copy of args (argv is char **; the copy lives until the next
 * parse, as a command's argv outlives its options), with what it printed on
 * stderr in msg. */
static cli_result parse(const char *const *args, int argc, opts *o, int *first, char *msg,
                        size_t size)
{
    static char copies[16][64];
    char *argv[16];
    for (int i = 0; i < argc; i++)
        argv[i] = strcpy(copies[i], args[i]);
    fflush(stderr);
    int saved = dup(2);
    FILE *tmp = tmpfile();
    dup2(fileno(tmp), 2);
    cli_result r = cli_parse("t", NULL, table, argc, argv, o, first);
    fflush(stderr);
    dup2(saved, 2);
    close(saved);
    rewind(tmp);
    size_t n = fread(msg, 1, size - 1, tmp);
    msg[n] = '\0';
    fclose(tmp);
    return r;
}

static void test_stores(void)
{
    opts o = {.count = -1, .port = -1};
    char msg[512];
    int first = -1;
    const char *args[] = {"t",      "--name",  "abc",     "--count=42",   "--port",
                          "8080",   "--ratio", "0.25",    "--depth=2",    "--verbose",
                          "--pick", "x",       "--hz=60", "--bytes=8192", "operand"};
    cli_result r = parse(args, 15, &o, &first, msg, sizeof msg);
    CHECK(r == CLI_OK && msg[0] == '\0', "a good line parses (%d, \"%s\")", r, msg);
    CHECK(o.name && strcmp(o.name, "abc") == 0, "--name stored");
    CHECK(o.count == 42, "--count=42 stored (%ld)", o.count);
    CHECK(o.port == 8080, "--port stored in an int (%d)", o.port);
    CHECK(o.ratio == 0.25 && o.inner.depth == 2, "--ratio and the nested --depth stored");
    CHECK(o.verbose == 1, "--verbose set");
    CHECK(o.calls == 1 && o.called_with && strcmp(o.called_with, "x") == 0,
          "--pick's call made once with its value");
    CHECK(o.hz == 60 && o.bytes == 8192, "--hz's call and --bytes stored (%ld, %ld)", o.hz,
          o.bytes);
    CHECK(first == 14, "the operand is left at 14 (%d)", first);

    opts none = {0};
    const char *flag_call[] = {"t", "--a-long-option-name-here"};
    r = parse(flag_call, 2, &none, NULL, msg, sizeof msg);
    CHECK(r == CLI_OK && none.calls == 1 && none.called_with == NULL,
          "a flag's call gets no value");
}

/* one refusal: the result, the message to the byte, and the options untouched */
static void refused(const char *a1, const char *a2, const char *want)
{
    opts o = {.count = 7, .port = 7, .ratio = 0.5, .inner = {0.5}, .bytes = 7, .hz = 7};
    char msg[512];
    const char *args[] = {"t", a1, a2};
    cli_result r = parse(args, a2 ? 3 : 2, &o, NULL, msg, sizeof msg);
    CHECK(r == CLI_ERROR && strcmp(msg, want) == 0, "%s %s: \"%s\" (want \"%s\")", a1, a2 ? a2 : "",
          msg, want);
    CHECK(o.count == 7 && o.port == 7 && o.ratio == 0.5 && o.inner.depth == 0.5 && !o.verbose &&
              !o.name && o.bytes == 7 && o.hz == 7,
          "%s %s: nothing stored", a1, a2 ? a2 : "");
}

static void test_refusals(void)
{
    refused("--count", "51", "terrad t: --count: must be an integer in [0, 50] (got '51')\n");
    refused("--count", "1.5", "terrad t: --count: must be an integer in [0, 50] (got '1.5')\n");
    refused("--port", "65536",
            "terrad t: --port: must be an integer in [0, 65535] (got '65536')\n");
    refused("--ratio", "2", "terrad t: --ratio: must be a number in [0, 1] (got '2')\n");
    refused("--depth", "nan", "terrad t: --depth: must be a number in [0.001, 10] (got 'nan')\n");
    refused("--pick", "bad", "terrad t: --pick: \"bad\" is not a pick\n");
    refused("--hz", "0", "terrad t: --hz: must be an integer in [1, 1000] (got '0')\n");
    refused("--hz", "60.5", "terrad t: --hz: must be an integer in [1, 1000] (got '60.5')\n");
    refused("--bytes", "1099511627777",
            "terrad t: --bytes: must be an integer in [4096, 2^40] (got '1099511627777')\n");
    refused("--verbose=1", NULL, "terrad t: '--verbose' takes no value (see terrad t --help)\n");
    refused("--count", NULL, "terrad t: '--count' needs a value (see terrad t --help)\n");
    refused("--nope", NULL, "terrad t: unknown option '--nope' (see terrad t --help)\n");
    refused("operand", NULL, "terrad t: unexpected argument 'operand' (see terrad t --help)\n");
}

static void test_help(void)
{
    FILE *f = tmpfile();
    cli_print_help(f, "t", NULL, table);
    rewind(f);
    char text[2048];
    size_t n = fread(text, 1, sizeof text - 1, f);
    text[n] = '\0';
    fclose(f);
    const char *want = "usage: terrad t [options]\n"
                       "\n"
                       "options:\n"
                       "  --name S              a string\n"
                       "  --count N             a long; N in [0, 50]\n"
                       "  --port N              an int\n"
                       "                        second line; N in [0, 65535]\n"
                       "  --ratio X             a double; X in [0, 1]\n"
                       "  --depth M             a nested double; M in [0.001, 10]\n"
                       "  --verbose             a flag\n"
                       "  --pick P              a call\n"
                       "  --a-long-option-name-here\n"
                       "                        wraps\n"
                       "  --bytes N             a large power of two; N in [4096, 2^40]\n"
                       "  --ticks N             a last line too long for its range to follow "
                       "it on the same line;\n"
                       "                        N in [0, 1e8]\n"
                       "  --hz N                a call given an integer; N in [1, 1000]\n"
                       "  --help                this text\n";
    CHECK(strcmp(text, want) == 0, "--help text:\n%s", text);
}

/* a bound as --help and the refusals show it */
static void test_numbers(void)
{
    const struct {
        double x;
        const char *want;
    } cases[] = {{0, "0"},
                 {65535, "65535"},
                 {0.001, "0.001"},
                 {1e-4, "0.0001"},
                 {0.95, "0.95"},
                 {86400000, "86400000"},
                 {1e7, "1e7"},
                 {1e8, "1e8"},
                 {1e9, "1e9"},
                 {1e6, "1e6"},
                 {999999, "999999"},
                 {1099511627776.0, "2^40"},
                 {1 << 20, "2^20"},
                 {1048577, "1048577"},
                 {-1e6, "-1e6"},
                 {4096, "4096"},
                 {9007199254740992.0, "2^53"}};
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        char buf[32];
        cli_format_number(buf, sizeof buf, cases[i].x);
        CHECK(strcmp(buf, cases[i].want) == 0, "%.17g shown as \"%s\" (want \"%s\")", cases[i].x,
              buf, cases[i].want);
    }
}

int main(void)
{
    test_stores();
    test_refusals();
    test_help();
    test_numbers();
    return check_report();
}
