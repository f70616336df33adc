/*
 * array.c: the one growable array of the code base (base.h). Scratch buffers
 * of the tick, pose tables, frame buffers and parser lists all grow through
 * array_grow, so capacity doubling and overflow checks live in one place.
 */
#include "base/base.h"

#include <stdlib.h>

int array_grow(void **items, int64_t *capacity, int64_t needed, size_t elem_size)
{
    if (needed <= *capacity)
        return 0;
    if (needed < 0 || elem_size == 0)
        return -1;
    int64_t cap = *capacity > 0 ? *capacity : 16;
    while (cap < needed) {
        if (cap > INT64_MAX / 2)
            return -1;
        cap *= 2;
    }
    if ((uint64_t)cap > SIZE_MAX / elem_size)
        return -1;
    void *grown = realloc(*items, (size_t)cap * elem_size);
    if (!grown)
        return -1;
    *items = grown;
    *capacity = cap;
    return 0;
}
