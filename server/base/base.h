/*
 * base: the small pieces every subsystem uses — logging, monotonic time,
 * per-stage timing series (mean and p99), the process's memory, one integer
 * hash, one growable array, one whole-file reader, one set of JSON field
 * readers whose errors name the field, one command-line parser (getopt_long)
 * and thread-ownership checks. Nothing here knows about terrain; it exists so that each subsystem
 * does not grow its own copy of these helpers. It is the bottom layer: it
 * includes no other subsystem.
 */
#ifndef TERRAD_BASE_H
#define TERRAD_BASE_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <time.h>

/* Log lines go to stderr, one line each, prefixed with the level. */
void log_info(const char *fmt, ...) __attribute__((format(printf, 1, 2)));
void log_warn(const char *fmt, ...) __attribute__((format(printf, 1, 2)));
void log_error(const char *fmt, ...) __attribute__((format(printf, 1, 2)));
/* Quiet mode drops info lines (used by `terrad simulate`, whose stdout is JSON). */
void log_set_quiet(int quiet);

/* Milliseconds from a monotonic clock. */
double time_now_ms(void);
/* The moment ms milliseconds from now (in the past when ms < 0) on clock, as
 * pthread_cond_timedwait wants it: the condition's own clock (CLOCK_REALTIME,
 * or CLOCK_MONOTONIC for one made with that attribute). */
struct timespec time_after_ms(clockid_t clock, double ms);

/* Test hook (base/fault.c): with TERRAD_FAULT_STALL=FILE set, the calling
 * thread waits while FILE exists and names it ("tick", "net"). */
void fault_stall(const char *thread);

/* A growing series of samples, for per-stage mean and p99. */
typedef struct stat_series {
    double *samples;
    size_t count, capacity;
} stat_series;

void stat_series_add(stat_series *s, double value);
double stat_series_mean(const stat_series *s);
double stat_series_percentile(const stat_series *s, double p); /* p in [0,100] */
void stat_series_free(stat_series *s);

/* The data of a file compiled into the binary (shaders/, the default scene,
 * docs/openapi.yaml; base/embedded.c), NUL-terminated, or NULL if none is
 * embedded under that name (a path relative to the repository root, e.g.
 * "shaders/classify.comp"). When size is not NULL it receives the length. */
const char *embedded_file_find(const char *name, size_t *size);

/* Peak resident set size of this process in bytes (VmHWM), 0 if unknown. */
uint64_t proc_peak_rss_bytes(void);

/* lowbias32 (Chris Wellons' "hash prospector"): a well-mixed 32-bit integer
 * finaliser, the one copy. Heights depend on its exact bits: the jump
 * flooding's tie order (sim_cell_hash, and its GLSL twin in
 * shaders/common.glsl) and the dunes' lattice noise (world/terrain_base.c). */
#define HASH_LOWBIAS32_M1 0x7feb352du /* its multipliers, for vector forms of it */
#define HASH_LOWBIAS32_M2 0x846ca68bu
static inline uint32_t hash_lowbias32(uint32_t x)
{
    x ^= x >> 16;
    x *= HASH_LOWBIAS32_M1;
    x ^= x >> 15;
    x *= HASH_LOWBIAS32_M2;
    x ^= x >> 16;
    return x;
}

/* Error text carried out of a failing call: one line, names the cause. */
typedef struct error_text {
    char message[256];
} error_text;

void error_set(error_text *err, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
/* Prepend "prefix" + sep to the message a lower layer wrote. */
void error_prefix(error_text *err, const char *prefix, const char *sep);

/* ---- The sim's stage names, written once ----
 * X-macro lists: sim.h generates sim_stage_times and sim_stage_memory from
 * them, and metrics, serve and simulate name the stages through them. They
 * live here, at the bottom, because metrics sits below sim and needs the
 * same names. SIM_STAGE_LIST: the backend's timed stages, in tick order.
 * SIM_MEMORY_STAGE_LIST: what the sim's scratch memory is held for. */
#define SIM_STAGE_LIST(X) X(depth) X(classify) X(jump_flood) X(displace) X(even_slopes) X(transfer)
#define SIM_MEMORY_STAGE_LIST(X)                                                                   \
    X(depth)                                                                                       \
    X(classify) X(jump_flood) X(displace) X(even_slopes) X(backend_other) X(model) X(gather_scatter)
/* A list entry as a string and a comma: {SIM_STAGE_LIST(SIM_STAGE_NAME)}. */
#define SIM_STAGE_NAME(name) #name,

/* ---- One growable array (array.c) ----
 * *items holds *capacity elements of elem_size bytes. Makes room for at least
 * `needed` (capacity at least doubles, so appends are amortised O(1)); the new
 * tail is not initialised. Returns 0, or -1 with *items and *capacity
 * unchanged when memory runs out or the size would overflow. */
int array_grow(void **items, int64_t *capacity, int64_t needed, size_t elem_size);

/* ---- Whole files (file.c) ---- */
/* Reads all of path into a malloc'd buffer with a NUL byte after the last
 * (so text parsers can use it; *len excludes it). Refuses files larger than
 * max_bytes (0: no limit but memory). Returns 0, or -1 with err naming the
 * path and the cause. */
int file_read_all(const char *path, size_t max_bytes, uint8_t **data, size_t *len, error_text *err);
/* len bytes into path, durably: written to path.tmp, fsynced, renamed over
 * path, the directory fsynced (a crash leaves the old file or the new one,
 * never a part). 0, or -1 with err naming the path (path.tmp removed). */
int file_write_durably(const char *path, const void *data, size_t len, error_text *err);
/* fsync of a directory (a rename or unlink in it made durable); errors ignored. */
void file_sync_dir(const char *dir);

/* ---- JSON field readers (json_fields.c) ----
 * For strict configuration and scene parsing with cJSON: every message names
 * the JSON path of the offending value, e.g.
 * "colliders[2].motion.velocity[0]: must be a finite number". `path` is the
 * path of obj ("" at the root). The getters return 1 when the key is present
 * and valid, 0 when absent, -1 (err set) when present but wrong. */
typedef struct cJSON cJSON;

/* "world" + "width" -> "world.width"; "" + "name" -> "name". Cut, never overrun. */
void json_path_join(char *out, size_t size, const char *parent, const char *key);
void json_path_index(char *out, size_t size, const char *parent, int i);
/* "a number", "a string", "an object", ... for messages. */
const char *json_type_name(const cJSON *v);
/* root_name names obj in the message when path is "" (e.g. "scene"). */
int json_expect_object(const cJSON *v, const char *path, const char *root_name, error_text *err);
/* Every key of obj must be in allowed (NULL-terminated), once. context, if
 * not NULL, ends the message: "p: unknown key for <context>". */
int json_check_keys(const cJSON *obj, const char *path, const char *const *allowed,
                    const char *context, error_text *err);
/* A finite number in [lo, hi]. */
int json_get_number(const cJSON *obj, const char *path, const char *key, double lo, double hi,
                    double *out, error_text *err);
/* Like json_get_number, but absence is an error (returns 0 or -1). */
int json_require_number(const cJSON *obj, const char *path, const char *key, double lo, double hi,
                        double *out, error_text *err);
/* A finite number in (0, hi]; required: absence is an error. */
int json_get_positive(const cJSON *obj, const char *path, const char *key, double hi, int required,
                      double *out, error_text *err);
/* An integer in [lo, hi]; required: absence is an error. */
int json_get_integer(const cJSON *obj, const char *path, const char *key, double lo, double hi,
                     int required, double *out, error_text *err);
/* A string shorter than size. */
int json_get_string(const cJSON *obj, const char *path, const char *key, char *out, size_t size,
                    error_text *err);
/* A boolean. */
int json_get_bool(const cJSON *obj, const char *path, const char *key, int *out, error_text *err);
/* An array of exactly n finite numbers, each with |x| <= limit. */
int json_get_vector(const cJSON *obj, const char *path, const char *key, int n, double limit,
                    double *out, error_text *err);
/* o's unformatted text (the caller frees it), and o deleted: a reply or body
 * built as an object and sent as text. NULL when out of memory (o NULL too:
 * a create that failed, so a caller need not test it first). */
char *json_print_delete(cJSON *o);

/* ---- Command lines (cli.c): one parser, on getopt_long, for every command ----
 * A command describes its options in a table (ended by {0}); cli_parse
 * accepts "--opt value" and "--opt=value", answers "--help" by printing the
 * command's options to stdout, and refuses an unknown option ("unknown option
 * '--x'"), a missing value ("'--x' needs a value") and a value given to a
 * flag, each on stderr prefixed with "terrad CMD: ".
 *
 * A row also says where its value goes, as nginx's command tables do
 * (ngx_conf_set_str_slot and an offsetof): cli_parse stores a string, an
 * integer or a number in [lo, hi], or a flag's 1, at an offset into the
 * command's options struct (ctx), so a plain option is written once, in its
 * row; an option that needs code names a function (CLI_CALLS, or
 * CLI_CALLS_LONG for an integer in [lo, hi] checked before the call). The
 * CLI_AT_* macros give a row's tail and check the field's type. A row's range
 * is written once, in the row: cli_parse refuses a value outside it and --help
 * prints it ("N in [0, 65535]", from lo and hi), so no help text repeats it. */
typedef enum cli_store {
    CLI_CALL = 0,  /* call(ctx, value, err): an option that needs code */
    CLI_STRING,    /* const char *: the value itself (argv outlives the options) */
    CLI_LONG,      /* long: an integer in [lo, hi] (cli_parse_long's refusal) */
    CLI_INT,       /* int: an integer in [lo, hi] (cli_parse_long's refusal) */
    CLI_DOUBLE,    /* double: a number in [lo, hi] (cli_parse_double's refusal) */
    CLI_FLAG,      /* int: set to 1 (a flag: value_name NULL) */
    CLI_CALL_LONG, /* call(ctx, value, err) once value is an integer in [lo, hi] */
} cli_store;

typedef struct cli_option {
    const char *name;       /* without the dashes */
    const char *value_name; /* NULL: a flag; else the value's name in --help ("N", "FILE") */
    const char *help;       /* one or more lines; '\n' starts a new indented line */
    cli_store store;
    size_t offset; /* of the field in ctx, for every store but CLI_CALL */
    double lo,
        hi; /* CLI_LONG, CLI_INT, CLI_DOUBLE, CLI_CALL_LONG: the range (whole for integers) */
    int (*call)(void *ctx, const char *value, error_text *err); /* CLI_CALL: 0, or -1 and err */
} cli_option;

/* offsetof(type, field), refused at compile time unless the field is a ctype */
#define CLI_FIELD_(type, field, ctype)                                                             \
    (offsetof(type, field) + 0 * sizeof((ctype *){&((type *)0)->field}))
#define CLI_AT_STRING(type, field)                                                                 \
    .store = CLI_STRING, .offset = CLI_FIELD_(type, field, const char *)
#define CLI_AT_LONG(type, field, min, max)                                                         \
    .store = CLI_LONG, .offset = CLI_FIELD_(type, field, long), .lo = (min), .hi = (max)
#define CLI_AT_INT(type, field, min, max)                                                          \
    .store = CLI_INT, .offset = CLI_FIELD_(type, field, int), .lo = (min), .hi = (max)
#define CLI_AT_DOUBLE(type, field, min, max)                                                       \
    .store = CLI_DOUBLE, .offset = CLI_FIELD_(type, field, double), .lo = (min), .hi = (max)
#define CLI_AT_FLAG(type, field) .store = CLI_FLAG, .offset = CLI_FIELD_(type, field, int)
#define CLI_CALLS(function) .store = CLI_CALL, .call = (function)
#define CLI_CALLS_LONG(function, min, max)                                                         \
    .store = CLI_CALL_LONG, .call = (function), .lo = (min), .hi = (max)

typedef enum cli_result {
    CLI_OK = 0,    /* every option was handled; *first_operand indexes the rest */
    CLI_HELP = 1,  /* --help was printed: exit 0 */
    CLI_ERROR = 2, /* a message was printed: exit 2 */
} cli_result;

/* Each option is stored or its row's call made once, in order (a refusal
 * fills err and is printed as "terrad CMD: --name: <err>"). argv[0] is
 * skipped, as getopt does: pass the command's own argv (argv[0] = the
 * command's name). Operands (arguments that are not options) are left in
 * place after *first_operand when first_operand is not NULL, and refused
 * otherwise. */
cli_result cli_parse(const char *command, const char *usage, const cli_option *options, int argc,
                     char **argv, void *ctx, int *first_operand);
/* One option's value where its row says (what cli_parse does with each):
 * stored in a field of ctx within the row's range, or the row's call made;
 * 0, or -1 with err saying why ("must be an integer in [0, 65535] (got
 * '70000')"). A CLI_STRING row keeps the pointer: value must outlive ctx's
 * use. Lets a config file's keys go through the same rows (serve --config). */
int cli_store_value(const cli_option *row, void *ctx, const char *value, error_text *err);
/* The row of options named name (without the dashes), or NULL. */
const cli_option *cli_find(const cli_option *options, const char *name);
/* The help text cli_parse prints for --help: usage, then each option's help,
 * a numeric row's ending "; N in [lo, hi]" (its value's name and its range). */
void cli_print_help(FILE *out, const char *command, const char *usage, const cli_option *options);
/* x as --help and the refusals show a bound: plainly (65535, 0.001,
 * 86400000), or a large power of ten or two as 1e8 or 2^40. */
void cli_format_number(char *buf, size_t size, double x);
/* An integer in [lo, hi] from an option's value; err says why not. */
int cli_parse_long(const char *value, long lo, long hi, long *out, error_text *err);
int cli_parse_double(const char *value, double lo, double hi, double *out, error_text *err);

/* ---- Thread ownership (thread_owner.c) ----
 * A function documented as "sim thread only" asserts it: the owner records
 * itself once when its thread starts, and each thread-owned entry point
 * checks. The checks compile to nothing unless TERRAD_THREAD_CHECKS is set
 * (debug and sanitizer builds set it); a failed check names the owner and
 * the function and aborts. */
typedef struct thread_owner {
    const char *name;  /* "sim", "net", "http", "compaction" */
    unsigned long tid; /* pthread_self() of the owner; 0: not yet claimed */
} thread_owner;

void thread_owner_claim(thread_owner *o, const char *name);
void thread_owner_release(thread_owner *o);
void thread_owner_check(const thread_owner *o, const char *function);
#ifdef TERRAD_THREAD_CHECKS
#define THREAD_OWNED(owner) thread_owner_check((owner), __func__)
#else
#define THREAD_OWNED(owner) ((void)(owner))
#endif

/* ---- Authentication (auth.c) ----
 * Who may do what: a table of tokens, each known only by its SHA-256, with
 * a role and a name, read from an auth file (docs/security.md): one line
 * per token, "ROLE NAME SHA256HEX", '#' comments (no token is ever given
 * in clear on a command line or in a config). Any thread may check a token;
 * auth_reload (SIGHUP) swaps the entries in under a lock and bumps the
 * generation, so the net thread can close connections whose token went
 * away. Empty (no file): auth is off and every client is an admin, as
 * before roles existed. */
typedef enum auth_role { AUTH_NONE = 0, AUTH_VIEWER, AUTH_DRIVER, AUTH_ADMIN } auth_role;
#define AUTH_NAME_MAX 64
#define AUTH_TOKEN_PREFIX "tdk_" /* what terrad token add makes: never mistaken for a hash */
typedef struct auth_table auth_table;

/* NULL on out of memory, or with err naming the file and line when it is
 * malformed. path NULL: an empty table, auth off. */
auth_table *auth_create(const char *path, error_text *err);
void auth_free(auth_table *t);
/* Read the file again: 0 and the new entries in place, or -1 with err and the old ones kept. */
int auth_reload(auth_table *t, error_text *err);
int auth_enabled(const auth_table *t);         /* 1 once a file was given */
int auth_count(const auth_table *t);           /* tokens known now */
unsigned auth_generation(const auth_table *t); /* bumped by every successful reload */
/* The role of a presented token (AUTH_NONE: unknown), its entry's name into name
 * (may be NULL), and its hash into hash (may be NULL), for auth_role_of_hash. */
auth_role auth_check(auth_table *t, const char *token, char *name, size_t name_cap,
                     unsigned char hash[32]);
/* The role the entry with this hash has now (AUTH_NONE once revoked). */
auth_role auth_role_of_hash(auth_table *t, const unsigned char hash[32]);
const char *auth_role_name(auth_role r);
auth_role auth_role_parse(const char *name); /* AUTH_NONE if not a role */
/* The SHA-256 of token as 64 lowercase hex digits. */
void auth_hash_hex(const char *token, char out[65]);
/* A fresh random token (AUTH_TOKEN_PREFIX + 43 base64url characters); -1 without entropy. */
int auth_new_token(char *out, size_t cap);
/* One line of an auth file: 1 for an entry, 0 for a blank or comment line, -1 with err. */
int auth_parse_line(const char *line, auth_role *role, char *name, unsigned char hash[32],
                    error_text *err);

/* Standard base64 (RFC 4648, '+' '/', '=' padding optional) decoded into out,
 * which holds at least strlen(in) * 3 / 4 + 3 bytes: the JetStream API's
 * "data" and "hdrs", a terrain edit's stamp. The byte count, or -1 when a
 * character is not base64. */
int64_t base64_decode(const char *in, uint8_t *out);

/* ---- TLS files (tls.c) ----
 * Checks a certificate and its private key before any port opens: each
 * readable, PEM, and the key the certificate's. -1 with err naming the file. */
int tls_check_pair(const char *cert_path, const char *key_path, error_text *err);

#endif
