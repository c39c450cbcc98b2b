/* The checks the C test programs share (tests/capi.rs builds them): CHECK reports a failed
 * condition with kpcn's last error and counts it; EXPECT compares a status. */
#ifndef KPCN_TEST_CHECK_H
#define KPCN_TEST_CHECK_H

#include <kpcn.h>
#include <stdio.h>

static int failures = 0;

#define CHECK(cond, ...)                                                          \
    do {                                                                          \
        if (!(cond)) {                                                            \
            fprintf(stderr, "FAIL %s:%d: %s — ", __FILE__, __LINE__, #cond);      \
            fprintf(stderr, __VA_ARGS__);                                         \
            fprintf(stderr, " (last error: %s)\n", kpcn_last_error());           \
            failures++;                                                           \
        }                                                                         \
    } while (0)

#define EXPECT(status, expected) \
    CHECK((status) == (expected), "got %d (%s)", (int)(status), kpcn_status_string(status))

#endif
