/*
 * net_requests_internal.h: the middle layer of the net thread (see net_client_internal.h) —
 * what a client's whole message asks for, checked and answered, turned into
 * hub commands and poses. Called by net.c with one reassembled message;
 * calls only net_client.c and net_control.c. Net thread only.
 */
#ifndef TERRAD_NET_REQUESTS_INTERNAL_H
#define TERRAD_NET_REQUESTS_INTERNAL_H

#include <stddef.h>

#include "net/net_client_internal.h"

/* A text message (NUL-terminated at text[len]). */
void net_handle_text(net_client *c, const char *text, size_t len);
/* A binary message (POSE_BATCH, PING, PONG). */
void net_handle_binary(net_client *c, const unsigned char *data, size_t len);

#endif
