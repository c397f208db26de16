/* The link over ARM semihosting: the board.h link API (usart_*) for the emulator build only,
 * uwb-fw-semihost.elf. Never in the flashed image: `bkpt 0xab` without a debugger that serves it
 * faults on silicon; the Makefile links this file into uwb-fw-semihost.elf alone (uwb-fw.elf keeps
 * usart.c), and the harness refuses an ELF without `semihost_link_open` for this transport.
 *
 * QEMU runs with `-semihosting-config enable=on,target=native` in a directory where the harness
 * made two FIFOs: LINK_IN (host -> guest frames) and LINK_OUT (guest -> host). One SYS_READ moves
 * whatever the host has written (up to RX_SIZE bytes) into guest memory in one trap, instead of one
 * byte per QEMU main-loop iteration through the emulated USART. Replies collect in a buffer that is
 * written with one SYS_WRITE before the guest waits for input again (or when it is full), so the
 * host sees every reply to what it sent before the guest blocks. The frame protocol on the pipes is
 * the one on the USART. End of input (the host closed LINK_IN) ends the emulator: SYS_EXIT, after
 * printing on QEMU's semihosting console (its log) how many ticks of TIM2 the guest ran: under
 * `-icount shift=0` its executed instructions, read by harness/bench/real_replay.py. */
#include <string.h>

#include "board.h"
#include "stm32f405_regs.h"

#ifndef UWB_LINK_SEMIHOST
#error "semihost_link.c is the emulator build's link only (uwb-fw-semihost.elf, make semihost)"
#endif

#define SYS_OPEN 0x01u
#define SYS_WRITE0 0x04u
#define SYS_WRITE 0x05u
#define SYS_READ 0x06u
#define SYS_EXIT 0x18u
#define ADP_STOPPED_APPLICATION_EXIT 0x20026u /* QEMU exits with status 0 */
#define ADP_STOPPED_RUNTIME_ERROR 0x20023u    /* ... with status 1 */
#define OPEN_RB 1u                            /* fopen mode "rb" */
#define OPEN_WB 5u                            /* fopen mode "wb" */

#define LINK_IN "uwb-link.in"
#define LINK_OUT "uwb-link.out"
#define RX_SIZE 8192u
#define TX_SIZE 4096u

static int32_t link_in = -1, link_out = -1;
static uint8_t rx_buf[RX_SIZE];
static uint32_t rx_len, rx_pos;
static uint8_t tx_buf[TX_SIZE];
static uint32_t tx_len;
static uint32_t ticks_seen;
static uint64_t ticks_total; /* TIM2 ticks (instructions under -icount) since usart_init */

static uint32_t semihost(uint32_t op, const void *args)
{
    register uint32_t r0 __asm__("r0") = op;
    register const void *r1 __asm__("r1") = args;
    __asm__ volatile("bkpt 0xab" : "+r"(r0) : "r"(r1) : "memory");
    return r0;
}

/* TIM2 is 32 bits (4.3 s of instructions under -icount): accumulated at every read, far more often. */
static void count_ticks(void)
{
    const uint32_t now = TIM2_CNT;
    ticks_total += (uint32_t)(now - ticks_seen);
    ticks_seen = now;
}

static uint32_t append(char *dst, uint32_t n, const char *s)
{
    while (*s != '\0') {
        dst[n++] = *s++;
    }
    return n;
}

static void semihost_exit(uint32_t reason)
{
    char text[64];
    char digits[21];
    uint32_t n, k = 0u;
    uint64_t v;
    count_ticks();
    v = ticks_total;
    do {
        digits[k++] = (char)('0' + (int)(v % 10u));
        v /= 10u;
    } while (v != 0u);
    n = append(text, 0u, "uwb-fw-semihost: link closed after ");
    while (k != 0u) {
        text[n++] = digits[--k];
    }
    n = append(text, n, " ticks\n");
    text[n] = '\0';
    (void)semihost(SYS_WRITE0, text); /* QEMU's semihosting console: its stdout, the device log */
    (void)semihost(SYS_EXIT, (const void *)reason); /* AArch32: the reason itself, not a block */
    for (;;) {
    }
}

static int32_t open_file(const char *name, uint32_t len, uint32_t mode)
{
    const uint32_t args[3] = {(uint32_t)name, mode, len};
    return (int32_t)semihost(SYS_OPEN, args);
}

int semihost_link_open(void);
int semihost_link_open(void)
{
    link_in = open_file(LINK_IN, sizeof LINK_IN - 1u, OPEN_RB);
    link_out = open_file(LINK_OUT, sizeof LINK_OUT - 1u, OPEN_WB);
    return link_in >= 0 && link_out >= 0;
}

void usart_init(const board_clocks_t *clk, uint32_t baud)
{
    (void)clk;
    (void)baud;
    rx_len = rx_pos = tx_len = 0u;
    ticks_seen = TIM2_CNT;
    ticks_total = 0u;
    if (!semihost_link_open()) {
        semihost_exit(ADP_STOPPED_RUNTIME_ERROR); /* not started by the harness's semihosting transport */
    }
}

void usart_flush(void)
{
    uint32_t done = 0u;
    while (done < tx_len) {
        const uint32_t args[3] = {(uint32_t)link_out, (uint32_t)&tx_buf[done], tx_len - done};
        const uint32_t left = semihost(SYS_WRITE, args); /* bytes NOT written */
        if (left >= tx_len - done) {
            semihost_exit(ADP_STOPPED_RUNTIME_ERROR); /* the host closed its end */
        }
        done = tx_len - left;
    }
    tx_len = 0u;
}

void usart_write(const uint8_t *data, size_t n)
{
    while (n != 0u) {
        size_t room = TX_SIZE - tx_len, k = n < room ? n : room;
        memcpy(&tx_buf[tx_len], data, k);
        tx_len += (uint32_t)k;
        data += k;
        n -= k;
        if (tx_len == TX_SIZE) {
            usart_flush();
        }
    }
}

size_t usart_rx_peek(const uint8_t **data)
{
    *data = &rx_buf[rx_pos];
    return (size_t)(rx_len - rx_pos);
}

size_t usart_rx_wait(const uint8_t **data)
{
    if (rx_pos == rx_len) {
        uint32_t args[3];
        uint32_t left;
        usart_flush(); /* the host may wait for these replies before it sends more */
        count_ticks();
        args[0] = (uint32_t)link_in;
        args[1] = (uint32_t)rx_buf;
        args[2] = RX_SIZE;
        left = semihost(SYS_READ, args); /* blocks until the host wrote something; bytes NOT read */
        if (left >= RX_SIZE) {
            semihost_exit(ADP_STOPPED_APPLICATION_EXIT); /* end of input: the session is over */
        }
        rx_pos = 0u;
        rx_len = RX_SIZE - left;
    }
    return usart_rx_peek(data);
}

void usart_rx_release(size_t n)
{
    rx_pos += (uint32_t)n;
}

uint32_t usart_rx_overruns(void) { return 0u; }
