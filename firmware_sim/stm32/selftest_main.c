/* Board self-test (no firmware core): prints one line describing the board layer, then echoes
 * every received byte. Used to check the board layer and QemuDevice's pty plumbing on their own:
 *   "uwb-stm32 selftest emulated=1 dwt=0 sysclk=168000000 fpu=0x40580000 busy1000=2011\n"
 * A received 'B' is not echoed: it runs busy(1000000) and answers "B=<cost>\n", the main-thread cost
 * from platform_cost_now(). Bytes the host sends meanwhile interrupt the loop; the answer must not
 * change (interrupt time is excluded from costs), and those bytes are echoed afterwards. */
#include "board.h"
#include "platform.h"
#include "stm32f405_regs.h"

static void put_dec(uint32_t v)
{
    uint8_t buf[10];
    unsigned n = 0;
    do {
        buf[sizeof buf - 1u - n] = (uint8_t)('0' + v % 10u);
        v /= 10u;
        n++;
    } while (v != 0u);
    usart_write(&buf[sizeof buf - n], n);
}

/* Exactly 2 instructions per iteration (subs + bne), plus entry/exit. */
__attribute__((noinline)) static void busy(uint32_t n)
{
    __asm__ volatile("1: subs %0, %0, #1\n"
                     "   bne 1b\n"
                     : "+r"(n)
                     :
                     : "cc");
}

int main(void)
{
    board_clocks_t clk;
    volatile float a = 1.5f, b = 2.25f;
    float c;
    uint32_t bits, t0, t1;

    board_clock_init(&clk);
    platform_stm32_init(&clk);
    usart_init(&clk, UWB_BAUD);

    c = a * b;
    __builtin_memcpy(&bits, &c, sizeof bits);
    t0 = platform_cost_now();
    busy(1000u);
    t1 = platform_cost_now();

    usart_puts("uwb-stm32 selftest emulated=");
    put_dec(clk.emulated);
    usart_puts(" dwt=");
    put_dec((uint32_t)platform_stm32_has_dwt());
    usart_puts(" sysclk=");
    put_dec(clk.sysclk_hz);
    usart_puts(" fpu=");
    usart_put_hex32(bits);
    usart_puts(" busy1000=");
    put_dec(t1 - t0);
    usart_puts("\n");

    for (;;) {
        const uint8_t *data;
        size_t n = usart_rx_wait(&data);
        if (data[0] == 'B') {
            uint32_t c0, c1;
            usart_rx_release(1);
            c0 = platform_cost_now();
            busy(1000000u);
            c1 = platform_cost_now();
            usart_puts("B=");
            put_dec(c1 - c0);
            usart_puts("\n");
            continue;
        }
        usart_write(data, n);
        usart_rx_release(n);
    }
}
