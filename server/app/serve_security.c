/*
 * serve_security.c: who may connect to `terrad serve`, and how the bytes
 * travel (docs/security.md). Read once before any port opens — a bad TLS
 * file or a malformed auth-file line stops the start, named — and the auth
 * file again on SIGHUP, between two ticks of the sim thread's loop: the new
 * table takes effect for the next hello or HTTP request at once, and the net
 * thread's heartbeat closes the connections whose token went away.
 */
#include <sys/resource.h>
#include <sys/stat.h>

#include "app/serve_internal.h"

int serve_security_open(const serve_options *o, auth_table **auth, error_text *err)
{
    *auth = NULL;
    if ((o->tls_cert && o->tls_cert[0]) || (o->tls_key && o->tls_key[0])) {
        if (tls_check_pair(o->tls_cert, o->tls_key, err) != 0)
            return -1;
        log_info("serve: TLS on both ports (certificate %s)", o->tls_cert);
    }
    if (!o->auth_file || !o->auth_file[0])
        return 0;
    *auth = auth_create(o->auth_file, err);
    if (!*auth)
        return -1;
    struct stat st;
    if (stat(o->auth_file, &st) == 0 && (st.st_mode & 0022))
        log_warn("serve: %s is writable by other users: whoever can write it can give "
                 "themselves any role",
                 o->auth_file);
    log_info("serve: %d tokens from %s (SIGHUP reads it again)", auth_count(*auth), o->auth_file);
    return 0;
}

void serve_security_reload(const serve_options *o, auth_table *auth)
{
    error_text err = {{0}};
    if (!auth || !o->auth_file || !o->auth_file[0]) {
        log_info("SIGHUP received: no --auth-file to read again (the log is stderr; stop with "
                 "SIGTERM)");
        return;
    }
    if (auth_reload(auth, &err) != 0) {
        log_error("SIGHUP received: %s: the tokens in use stay as they were", err.message);
        return;
    }
    log_info("SIGHUP received: auth file read again, %d tokens", auth_count(auth));
}

/* One string key: copied into buf, *out pointed at it. */
static int config_path(const cJSON *doc, const char *key, char *buf, size_t size, const char **out,
                       error_text *err)
{
    int r = json_get_string(doc, "", key, buf, size, err);
    if (r > 0)
        *out = buf;
    return r < 0 ? -1 : 0;
}

int serve_security_config(const cJSON *doc, serve_options *o, error_text *err)
{
    return config_path(doc, "auth_file", o->config_auth_file, sizeof o->config_auth_file,
                       &o->auth_file, err) ||
           config_path(doc, "tls_cert", o->config_tls_cert, sizeof o->config_tls_cert, &o->tls_cert,
                       err) ||
           config_path(doc, "tls_key", o->config_tls_key, sizeof o->config_tls_key, &o->tls_key,
                       err);
}

/* Descriptors: HTTP gets a quarter of RLIMIT_NOFILE (8..256 connections),
 * SERVE_FD_STORE stay free for the store and the process, and websocket
 * sockets are refused past the rest (net_conn.c), so that no stranger can
 * take the descriptors the store and the probes need. */
#define SERVE_FD_STORE 32

static unsigned serve_http_connections(void)
{
    struct rlimit rl;
    if (getrlimit(RLIMIT_NOFILE, &rl) != 0 || rl.rlim_cur == RLIM_INFINITY)
        return HTTP_DEFAULT_CONNECTIONS;
    long n = ((long)rl.rlim_cur - SERVE_FD_STORE) / 4;
    return n < 8 ? 8 : n > HTTP_DEFAULT_CONNECTIONS ? HTTP_DEFAULT_CONNECTIONS : (unsigned)n;
}

http_server *serve_http_open(const serve_options *o, auth_table *auth, http_status *status,
                             hub_worlds *worlds, int *fd_reserve, error_text *err)
{
    http_limits hl = {.connections = serve_http_connections(),
                      .heights_bytes_per_address = o->limits.max_heights_bytes_per_address,
                      .heights_bytes_total = o->limits.max_heights_bytes_in_flight,
                      .edit_max_cells = o->limits.max_edit_cells};
    hl.connections_per_ip = hl.connections < HTTP_DEFAULT_CONNECTIONS_PER_IP
                                ? hl.connections
                                : HTTP_DEFAULT_CONNECTIONS_PER_IP;
    *fd_reserve = SERVE_FD_STORE + (int)hl.connections;
    http_security sec = {
        .auth = auth, .tls_cert = o->tls_cert, .tls_key = o->tls_key, .worlds = worlds};
    return http_server_start_secure(o->http_port, o->bind_any, status, &hl, &sec, err);
}
