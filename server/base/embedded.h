/*
 * embedded.h: files compiled into the binary (shaders/ and the default scene).
 * The table is generated at build time by cmake/embed_files.cmake; names are
 * paths relative to the repository root, e.g. "shaders/classify.comp" or
 * "server/scene/default.json". Data is NUL-terminated; size excludes the NUL.
 */
#ifndef TERRAD_BASE_EMBEDDED_H
#define TERRAD_BASE_EMBEDDED_H

#include <stddef.h>

struct embedded_file {
    const char *name;
    const char *data;
    size_t size;
};

/* embedded_file_count entries, followed by a {NULL, NULL, 0} sentinel. */
extern const struct embedded_file embedded_files[];
extern const size_t embedded_file_count;

/* The data of the file called name (NUL-terminated), or NULL if none is
 * embedded under that name. When size is not NULL it receives the length. */
const char *embedded_file_find(const char *name, size_t *size);

#endif
