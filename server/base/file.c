/*
 * file.c: the one whole-file reader (base.h). Scenes, OBJ meshes, terrain
 * files, configuration and the store's snapshots are read whole, at start or
 * off the tick, with the same size limit and error wording.
 */
#include "base/base.h"

#include <errno.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

int file_read_all(const char *path, size_t max_bytes, uint8_t **data, size_t *len, error_text *err)
{
    *data = NULL;
    *len = 0;
    FILE *f = fopen(path, "rb");
    if (!f) {
        error_set(err, "%s: cannot open: %s", path, strerror(errno));
        return -1;
    }
    struct stat st;
    if (fstat(fileno(f), &st) != 0 || !S_ISREG(st.st_mode)) {
        error_set(err, "%s: not a regular file", path);
        fclose(f);
        return -1;
    }
    if (max_bytes && (uint64_t)st.st_size > max_bytes) {
        error_set(err, "%s: larger than %zu bytes", path, max_bytes);
        fclose(f);
        return -1;
    }
    size_t size = (size_t)st.st_size;
    uint8_t *buf = malloc(size + 1);
    if (!buf) {
        error_set(err, "%s: out of memory for %zu bytes", path, size);
        fclose(f);
        return -1;
    }
    size_t got = size ? fread(buf, 1, size, f) : 0;
    int failed = ferror(f);
    fclose(f);
    if (got != size || failed) {
        error_set(err, "%s: cannot read (%zu of %zu bytes)", path, got, size);
        free(buf);
        return -1;
    }
    buf[size] = 0;
    *data = buf;
    *len = size;
    return 0;
}
