/* embedded.c: lookup in the build-generated table of embedded files. */
#include "base/base.h"
#include "base/embedded_internal.h"

#include <string.h>

const char *embedded_file_find(const char *name, size_t *size)
{
    if (name == NULL)
        return NULL;
    for (size_t i = 0; i < embedded_file_count; i++) {
        if (strcmp(embedded_files[i].name, name) == 0) {
            if (size != NULL)
                *size = embedded_files[i].size;
            return embedded_files[i].data;
        }
    }
    return NULL;
}
