#include "time_ms.h"

uint32_t uwb_ms_of_us(uint64_t t_us)
{
    const uint32_t hi = (uint32_t)(t_us >> 32), lo = (uint32_t)t_us;
    uint32_t r = hi % 1000u, n, q1;
    n = (r << 16) | (lo >> 16);   /* r < 1000: n < 2^26 */
    q1 = n / 1000u;
    r = n % 1000u;
    n = (r << 16) | (lo & 0xFFFFu);
    return (q1 << 16) + n / 1000u;   /* the quotient's low 32 bits: q1, n / 1000 < 2^16 */
}
