/*
 * embedded_internal.h: the table of files compiled into the binary, shared
 * by base/embedded.c and the table cmake/embed_files.cmake generates at build
 * time (names are paths relative to the repository root; data is
 * NUL-terminated, size excludes the NUL). Everything else asks base.h's
 * embedded_file_find.
 */
#ifndef TERRAD_BASE_EMBEDDED_INTERNAL_H
#define TERRAD_BASE_EMBEDDED_INTERNAL_H

#include <stddef.h>

struct embedded_file {
    const char *name;
    const char *data;
    size_t size;
};

/* embedded_file_count entries, followed by a {NULL, NULL, 0} sentinel. */
extern const struct embedded_file embedded_files[];
extern const size_t embedded_file_count;

#endif
