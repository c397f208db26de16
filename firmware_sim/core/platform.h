/* Platform hooks the OS-free core needs. Implemented once per target (host/, stm32/). */
#ifndef UWB_PLATFORM_H
#define UWB_PLATFORM_H

#include <stdint.h>

/* Free-running cost counter: nanoseconds on the host, executed instructions on the emulated MCU.
 * Only differences are used, so wrap-around of the 32-bit value is harmless. */
uint32_t platform_cost_now(void);

/* Unit of platform_cost_now() (= protocol enum cost_unit). */
enum { PLATFORM_COST_NANOSECONDS = 0, PLATFORM_COST_INSTRUCTIONS = 1 };
uint8_t platform_cost_unit(void);

#endif
