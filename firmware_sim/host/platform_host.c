/* Host platform hooks: the cost clock is CLOCK_MONOTONIC in nanoseconds. */
#include <time.h>

#include "platform.h"

uint32_t platform_cost_now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint32_t)((uint64_t)ts.tv_sec * 1000000000u + (uint64_t)ts.tv_nsec);
}

uint8_t platform_cost_unit(void) { return (uint8_t)PLATFORM_COST_NANOSECONDS; }
