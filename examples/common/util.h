/* util.h — what the example's files share: a message into a caller's
 * buffer, and a monotonic clock. */
#ifndef EXAMPLES_UTIL_H
#define EXAMPLES_UTIL_H

#include <stddef.h>

/* printf(`fmt`, ...) into `err` (when `err` and `errlen` are given); -1. */
int util_fail(char *err, size_t errlen, const char *fmt, ...) __attribute__((format(printf, 3, 4)));
/* Seconds on a monotonic clock. */
double util_now(void);

#endif
