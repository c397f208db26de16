/* STM32F405 board layer: clocks, the link USART, the cost clock. Used by main_stm32.c. */
#ifndef UWB_BOARD_H
#define UWB_BOARD_H

#include <stddef.h>
#include <stdint.h>

/* Which USART carries the link: 1 = USART1 on PA9/PA10 (QEMU `-serial pty` #0, most F405 boards),
 * 3 = USART3 on PC10/PC11 (the Crazyflie 2.x expansion-deck UART1, QEMU `-serial` #2). */
#ifndef UWB_USART
#define UWB_USART 1
#endif
#ifndef UWB_BAUD
#define UWB_BAUD 115200u
#endif
/* External crystal; 8 MHz on the Crazyflie 2.x. */
#ifndef HSE_HZ
#define HSE_HZ 8000000u
#endif

typedef struct {
    uint32_t sysclk_hz; /* core clock */
    uint32_t pclk1_hz;  /* APB1 (USART2..5, TIM2..7) */
    uint32_t pclk2_hz;  /* APB2 (USART1, USART6) */
    uint8_t emulated;   /* 1: RCC is not modelled (QEMU); no clock tree was set up */
    uint8_t hse_ok;     /* 1: running from the PLL on HSE (168 MHz) */
} board_clocks_t;

/* Bring the core to 168 MHz from HSE through the PLL (5 flash wait states, ART caches on).
 * Every wait is bounded; on failure the part stays on the 16 MHz HSI. Under QEMU the RCC reads
 * as zero, which is detected and skipped. */
void board_clock_init(board_clocks_t *clk);

/* ---- usart.c: the link. RX is interrupt driven into a ring buffer, TX is polled. */
void usart_init(const board_clocks_t *clk, uint32_t baud);
void usart_write(const uint8_t *data, size_t n);
void usart_puts(const char *s);
void usart_put_hex32(uint32_t v);
/* Longest contiguous run of received bytes (0 if none); *data points into the ring. */
size_t usart_rx_peek(const uint8_t **data);
/* usart_rx_peek(), but sleeps (WFI) until at least one byte has arrived: never returns 0. */
size_t usart_rx_wait(const uint8_t **data);
/* Mark n bytes returned by usart_rx_peek() as consumed (re-enables reception if it was paused). */
void usart_rx_release(size_t n);
/* Bytes the ISR found in the data register while the ring was full. With the pause-on-full
 * policy this stays 0 under QEMU (its 1-byte RX register gives back-pressure); on silicon a
 * paused receiver overruns instead, counted here via SR.ORE. */
uint32_t usart_rx_overruns(void);
/* The RX interrupt's work (called from the vector in link_irq.S). */
void link_rx_isr(void);
/* Hand buffered replies to the host. The emulator's semihosting link (semihost_link.c, built with
 * UWB_LINK_SEMIHOST into uwb-fw-semihost.elf only) buffers them; the USART transmits each byte as it
 * is written, so there it is nothing and the flashed image carries no code for it. */
#ifdef UWB_LINK_SEMIHOST
void usart_flush(void);
#else
static inline void usart_flush(void) {}
#endif

/* ---- platform_stm32.c: the cost clock (platform.h). */
void platform_stm32_init(const board_clocks_t *clk);
/* 1 if the DWT cycle counter runs (silicon), 0 if not (QEMU: TIM2 under -icount is used). */
int platform_stm32_has_dwt(void);
/* Read by the interrupt wrapper (link_irq.S): the raw counter behind the cost clock (TIM2->CNT or
 * DWT->CYCCNT) and the running total of counter ticks spent in interrupts, which
 * platform_cost_now() subtracts. */
extern volatile uint32_t *platform_cost_counter;
extern volatile uint32_t platform_isr_ticks;

#endif
