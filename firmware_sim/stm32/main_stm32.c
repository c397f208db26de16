/* uwb-fw for the STM32F405: the platform-independent firmware served on the link USART.
 * RX bytes arrive by interrupt into a ring buffer; the main loop feeds them to firmware_feed() in
 * contiguous chunks and sleeps (WFI) when there is nothing to do. Replies are written by polling. */
#include "board.h"
#include "firmware.h"
#include "stm32f405_regs.h"

static firmware_t fw; /* static: keeps the estimator state off the stack */

static void write_cb(void *ctx, const uint8_t *data, size_t n)
{
    (void)ctx;
    usart_write(data, n);
}

int main(void)
{
    board_clocks_t clk;
    board_clock_init(&clk);
    platform_stm32_init(&clk);
    usart_init(&clk, UWB_BAUD);
    firmware_init(&fw, write_cb, (void *)0, "stm32f4");

    for (;;) {
        const uint8_t *data;
        size_t n = usart_rx_wait(&data);
        firmware_feed(&fw, data, n);
        usart_rx_release(n);
    }
}
