/*
 * check.h: the unit tests' one assertion macro. A failed CHECK prints where
 * and why and the test goes on, so one run shows every failure; main() ends
 * with `return check_report();`, which prints the closing "N passed, N
 * failed" line that CI reads.
 */
#ifndef TERRAD_TEST_CHECK_H
#define TERRAD_TEST_CHECK_H

#include <stdio.h>

static int passed, failed;

#define CHECK(cond, ...)                                                                           \
    do {                                                                                           \
        if (cond) {                                                                                \
            passed++;                                                                              \
        } else {                                                                                   \
            failed++;                                                                              \
            printf("FAIL %s:%d: ", __FILE__, __LINE__);                                            \
            printf(__VA_ARGS__);                                                                   \
            printf("\n");                                                                          \
            fflush(stdout);                                                                        \
        }                                                                                          \
    } while (0)

static inline int check_report(void)
{
    printf("%d passed, %d failed\n", passed, failed);
    return failed ? 1 : 0;
}

#endif
