/* Deterministic platform hooks for the fuzz targets: the cost clock is a counter, so feeding the
 * same bytes twice must produce the same output bytes (the firmware target checks that). */
#include "fuzz_common.h"
#include "platform.h"

static uint32_t fuzz_clock;

uint32_t platform_cost_now(void) { return fuzz_clock += 7u; }

uint8_t platform_cost_unit(void) { return (uint8_t)PLATFORM_COST_INSTRUCTIONS; }

void fuzz_clock_reset(void) { fuzz_clock = 0; }
