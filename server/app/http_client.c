/*
 * http_client.c: terrad's own small HTTP/1.0 client (http_client_internal.h):
 * one connection per request, read to the end. Blocking and small: `terrad
 * loadgen` uses it only before and after its driving, `terrad world` for one
 * lifecycle call; no tick ever waits on it.
 */
#define _POSIX_C_SOURCE 200809L

#include <netdb.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <unistd.h>

#include "app/http_client_internal.h"

int app_http_url(const char *url, char *host, size_t cap, int *port)
{
    const char *p = url && strncmp(url, "http://", 7) == 0 ? url + 7 : NULL;
    const char *colon = p ? strchr(p, ':') : NULL;
    if (!colon || colon == p || (size_t)(colon - p) >= cap)
        return -1;
    memcpy(host, p, (size_t)(colon - p));
    host[colon - p] = 0;
    char *end = NULL;
    long n = strtol(colon + 1, &end, 10);
    if (end == colon + 1 || (*end && strcmp(end, "/") != 0) || n <= 0 || n >= 65536)
        return -1;
    *port = (int)n;
    return 0;
}

static int write_all(int s, const char *p, size_t n)
{
    while (n > 0) {
        ssize_t w = write(s, p, n);
        if (w <= 0)
            return -1;
        p += w;
        n -= (size_t)w;
    }
    return 0;
}

/* The whole answer (malloc'd, NUL after it), or NULL. */
static char *read_all(int s, size_t *got)
{
    size_t cap = 65536;
    char *buf = malloc(cap + 1);
    ssize_t r;
    *got = 0;
    while (buf && (r = read(s, buf + *got, cap - *got)) > 0) {
        *got += (size_t)r;
        if (*got == cap) {
            char *bigger = realloc(buf, 2 * cap + 1);
            if (!bigger) {
                free(buf);
                return NULL;
            }
            buf = bigger;
            cap *= 2;
        }
    }
    if (buf)
        buf[*got] = 0;
    return buf;
}

int app_http_request(const char *host, int port, const char *method, const char *path,
                     const char *token, const char *body, size_t body_len, char **answer,
                     size_t *answer_len)
{
    char port_text[16];
    snprintf(port_text, sizeof port_text, "%d", port);
    struct addrinfo hints = {.ai_family = AF_UNSPEC, .ai_socktype = SOCK_STREAM}, *ai = NULL;
    if (getaddrinfo(host, port_text, &hints, &ai) != 0)
        return -1;
    int s = socket(ai->ai_family, ai->ai_socktype, ai->ai_protocol);
    int ok = s >= 0 && connect(s, ai->ai_addr, ai->ai_addrlen) == 0;
    freeaddrinfo(ai);
    char head[1024];
    int bearer = token && *token;
    int n = snprintf(head, sizeof head,
                     "%s %s HTTP/1.0\r\nHost: %s\r\n%s%.300s%sContent-Length: %zu\r\n%s\r\n",
                     method, path, host, bearer ? "Authorization: Bearer " : "",
                     bearer ? token : "", bearer ? "\r\n" : "", body ? body_len : 0,
                     body ? "Content-Type: application/json\r\n" : "");
    if (!ok || n <= 0 || (size_t)n >= sizeof head || write_all(s, head, (size_t)n) != 0 ||
        (body && write_all(s, body, body_len) != 0)) {
        if (s >= 0)
            close(s);
        return -1;
    }
    size_t got = 0;
    char *buf = read_all(s, &got);
    close(s);
    if (!buf)
        return -1;
    int status = 0;
    char *end = strstr(buf, "\r\n\r\n");
    if (!end || sscanf(buf, "HTTP/%*s %d", &status) != 1) {
        free(buf);
        return -1;
    }
    *answer_len = got - (size_t)(end + 4 - buf);
    memmove(buf, end + 4, *answer_len + 1);
    *answer = buf;
    return status;
}
