/*
 * cli.c: the one command-line parser (base.h), on getopt_long. Every command
 * (serve, simulate, export, bench, ...) describes its options in a table, so
 * "--opt value" and "--opt=value" both work, "terrad CMD --help" prints that
 * command's options, and a mistake is named the same way everywhere. A row
 * says where its value goes (cli_store_value): most are stored here, at an
 * offset into the command's options, the rest call their row's function.
 */
#include "base/base.h"

#include <errno.h>
#include <getopt.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#define CLI_OPTIONS_MAX 64
/* The help column starts at 24; a range that would take its last line past
 * 24 + 70 goes on a line of its own. */
#define CLI_HELP_COLUMNS 70

/* x as --help and the refusals show a bound: as written in C where that is
 * plain (65535, 0.001, 86400000), a large power of ten or two as 1e8 or 2^40
 * rather than 100000000 or 1099511627776. */
void cli_format_number(char *buf, size_t size, double x)
{
    double a = fabs(x);
    if (a >= 1e6 && a < 1e300 && x == floor(x)) {
        int e10 = (int)lround(log10(a)), e2 = (int)lround(log2(a));
        if (pow(10, e10) == a) {
            snprintf(buf, size, "%se%d", x < 0 ? "-1" : "1", e10);
            return;
        }
        if (ldexp(1, e2) == a) {
            snprintf(buf, size, "%s2^%d", x < 0 ? "-" : "", e2);
            return;
        }
        snprintf(buf, size, "%.0f", x);
        return;
    }
    snprintf(buf, size, "%.15g", x);
}

/* A numeric row's range, from its lo and hi: "N in [0, 65535]" (the value's
 * name, as the refusal says "must be an integer in [0, 65535]"). Empty for a
 * row without one. */
static void range_text(const cli_option *o, char *buf, size_t size)
{
    buf[0] = '\0';
    if (o->store != CLI_LONG && o->store != CLI_INT && o->store != CLI_DOUBLE &&
        o->store != CLI_CALL_LONG)
        return;
    char lo[32], hi[32];
    cli_format_number(lo, sizeof lo, o->lo);
    cli_format_number(hi, sizeof hi, o->hi);
    snprintf(buf, size, "%s in [%s, %s]", o->value_name ? o->value_name : "value", lo, hi);
}

void cli_print_help(FILE *out, const char *command, const char *usage, const cli_option *options)
{
    fprintf(out, "usage: terrad %s %s\n\noptions:\n", command, usage ? usage : "[options]");
    for (const cli_option *o = options; o->name; o++) {
        char left[64];
        snprintf(left, sizeof left, "--%s%s%s", o->name, o->value_name ? " " : "",
                 o->value_name ? o->value_name : "");
        fprintf(out, "  %-22s", left);
        if (strlen(left) > 22)
            fprintf(out, "\n  %-22s", "");
        const char *help = o->help ? o->help : "";
        for (const char *h = help; *h; h++) {
            fputc(*h, out);
            if (*h == '\n')
                fprintf(out, "  %-22s", "");
        }
        char range[96];
        range_text(o, range, sizeof range);
        if (range[0]) {
            const char *last = strrchr(help, '\n');
            size_t used = strlen(last ? last + 1 : help);
            if (!help[0])
                fputs(range, out);
            else if (used + 2 + strlen(range) <= CLI_HELP_COLUMNS)
                fprintf(out, "; %s", range);
            else
                fprintf(out, ";\n  %-22s%s", "", range);
        }
        fputc('\n', out);
    }
    fprintf(out, "  %-22s%s\n", "--help", "this text");
}

int cli_store_value(const cli_option *o, void *ctx, const char *value, error_text *err)
{
    char *field = (char *)ctx + o->offset;
    long x;
    switch (o->store) {
    case CLI_STRING:
        *(const char **)(void *)field = value;
        return 0;
    case CLI_LONG:
        return cli_parse_long(value, (long)o->lo, (long)o->hi, (long *)(void *)field, err);
    case CLI_INT:
        if (cli_parse_long(value, (long)o->lo, (long)o->hi, &x, err) != 0)
            return -1;
        *(int *)(void *)field = (int)x;
        return 0;
    case CLI_DOUBLE:
        return cli_parse_double(value, o->lo, o->hi, (double *)(void *)field, err);
    case CLI_FLAG:
        *(int *)(void *)field = 1;
        return 0;
    case CLI_CALL_LONG:
        if (cli_parse_long(value, (long)o->lo, (long)o->hi, &x, err) != 0)
            return -1;
        break;
    case CLI_CALL:
        break;
    }
    return o->call ? o->call(ctx, value, err) : -1;
}

const cli_option *cli_find(const cli_option *options, const char *name)
{
    for (const cli_option *o = options; o->name; o++)
        if (strcmp(o->name, name) == 0)
            return o;
    return NULL;
}

cli_result cli_parse(const char *command, const char *usage, const cli_option *options, int argc,
                     char **argv, void *ctx, int *first_operand)
{
    struct option longs[CLI_OPTIONS_MAX + 2];
    int n = 0;
    for (; options[n].name; n++) {
        if (n >= CLI_OPTIONS_MAX) {
            fprintf(stderr, "terrad %s: too many options in the table\n", command);
            return CLI_ERROR;
        }
        longs[n] = (struct option){
            options[n].name, options[n].value_name ? required_argument : no_argument, NULL, n};
    }
    const int help_index = n;
    longs[n] = (struct option){"help", no_argument, NULL, help_index};
    longs[n + 1] = (struct option){0};

    /* getopt keeps global state: start over for each command's argv, and
     * report errors ourselves (opterr = 0) so every message has one shape. */
    optind = 0;
    opterr = 0;
    /* "+": stop at the first operand, as POSIX does; ":" reports a missing value as ':'. */
    for (;;) {
        int at = optind ? optind : 1;
        int c = getopt_long(argc, argv, "+:", longs, NULL);
        if (c == -1)
            break;
        const char *arg = at < argc ? argv[at] : "";
        if (c == '?') {
            /* an unknown long option, or a value given to a flag (--flag=x) */
            const char *eq = strchr(arg, '=');
            int known_flag = 0;
            if (eq && arg[0] == '-' && arg[1] == '-')
                for (int i = 0; i < n; i++)
                    if (!options[i].value_name &&
                        strlen(options[i].name) == (size_t)(eq - arg - 2) &&
                        strncmp(options[i].name, arg + 2, (size_t)(eq - arg - 2)) == 0)
                        known_flag = 1;
            if (known_flag)
                fprintf(stderr, "terrad %s: '%.*s' takes no value (see terrad %s --help)\n",
                        command, (int)(eq - arg), arg, command);
            else
                fprintf(stderr, "terrad %s: unknown option '%s' (see terrad %s --help)\n", command,
                        arg, command);
            return CLI_ERROR;
        }
        if (c == ':') {
            fprintf(stderr, "terrad %s: '%s' needs a value (see terrad %s --help)\n", command, arg,
                    command);
            return CLI_ERROR;
        }
        if (c == help_index) {
            cli_print_help(stdout, command, usage, options);
            return CLI_HELP;
        }
        error_text err = {{0}};
        if (cli_store_value(&options[c], ctx, optarg, &err) != 0) {
            fprintf(stderr, "terrad %s: --%s: %s\n", command, options[c].name,
                    err.message[0] ? err.message : "invalid");
            return CLI_ERROR;
        }
    }
    if (optind < argc && !first_operand) {
        fprintf(stderr, "terrad %s: unexpected argument '%s' (see terrad %s --help)\n", command,
                argv[optind], command);
        return CLI_ERROR;
    }
    if (first_operand)
        *first_operand = optind;
    return CLI_OK;
}

int cli_parse_long(const char *value, long lo, long hi, long *out, error_text *err)
{
    char *end = NULL;
    errno = 0;
    long x = strtol(value, &end, 10);
    if (errno || end == value || *end || x < lo || x > hi) {
        char l[32], h[32];
        cli_format_number(l, sizeof l, (double)lo);
        cli_format_number(h, sizeof h, (double)hi);
        error_set(err, "must be an integer in [%s, %s] (got '%s')", l, h, value);
        return -1;
    }
    *out = x;
    return 0;
}

int cli_parse_double(const char *value, double lo, double hi, double *out, error_text *err)
{
    char *end = NULL;
    errno = 0;
    double x = strtod(value, &end);
    if (errno || end == value || *end || !isfinite(x) || x < lo || x > hi) {
        char l[32], h[32];
        cli_format_number(l, sizeof l, lo);
        cli_format_number(h, sizeof h, hi);
        error_set(err, "must be a number in [%s, %s] (got '%s')", l, h, value);
        return -1;
    }
    *out = x;
    return 0;
}
