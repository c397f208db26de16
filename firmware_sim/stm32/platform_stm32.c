/* STM32F405 platform: clock tree and the cost clock of platform.h.
 *
 * Cost clock:
 *  - QEMU (netduinoplus2) with `-icount shift=0`: virtual time advances 1 ns per executed guest
 *    instruction and QEMU clocks TIM2 at a fixed 1 GHz, so TIM2->CNT counts exactly one tick per
 *    instruction. Unit reported: INSTRUCTIONS. (Without -icount the ticks are virtual ns that track
 *    host time; the unit is then nominal only.)
 *  - Silicon: the DWT cycle counter runs (QEMU 7.2 has no DWT: it reads 0). Cycles are turned into
 *    nanoseconds at the core clock so the protocol's NANOSECONDS unit holds. Detected at start-up,
 *    so one ELF serves both. */
#include "board.h"
#include "platform.h"
#include "stm32f405_regs.h"

#define HSI_HZ 16000000u
#define SYSCLK_TARGET_HZ 168000000u
#define RCC_WAIT_LOOPS 200000u /* > 100 ms at 16 MHz: HSE start-up is typically 2 ms */

static int wait_set(volatile uint32_t *reg, uint32_t mask, uint32_t value)
{
    uint32_t n;
    for (n = 0; n < RCC_WAIT_LOOPS; n++) {
        if ((*reg & mask) == value) {
            return 1;
        }
    }
    return 0;
}

static uint32_t apb_div(uint32_t ppre)
{
    return (ppre & 4u) != 0u ? 2u << (ppre & 3u) : 1u; /* 0xx: /1, 100: /2, 101: /4, 110: /8, 111: /16 */
}

/* What the clock tree is actually set to (also right when a bootloader configured it). */
static void clocks_from_registers(board_clocks_t *clk)
{
    const uint32_t cfgr = RCC_CFGR;
    uint32_t sys = HSI_HZ;
    if ((cfgr & RCC_CFGR_SWS_MASK) == (1u << 2)) {
        sys = HSE_HZ;
    } else if ((cfgr & RCC_CFGR_SWS_MASK) == RCC_CFGR_SWS_PLL) {
        const uint32_t pll = RCC_PLLCFGR;
        const uint32_t src = (pll & RCC_PLLCFGR_SRC_HSE) != 0u ? HSE_HZ : HSI_HZ;
        const uint32_t m = pll & 0x3Fu, n = (pll >> 6) & 0x1FFu, p = (((pll >> 16) & 3u) + 1u) * 2u;
        if (m != 0u) {
            sys = (uint32_t)(((uint64_t)src / m * n) / p);
        }
    }
    clk->sysclk_hz = sys;
    clk->pclk1_hz = sys / apb_div((cfgr >> 10) & 7u);
    clk->pclk2_hz = sys / apb_div((cfgr >> 13) & 7u);
}

void board_clock_init(board_clocks_t *clk)
{
    const uint32_t pll_m = HSE_HZ / 1000000u; /* 1 MHz PLL input */
    const uint32_t pll_n = 336u;              /* 336 MHz VCO */
    const uint32_t pll_p = 2u;                /* 168 MHz SYSCLK */
    const uint32_t pll_q = 7u;                /* 48 MHz USB/SDIO */

    clk->emulated = 0;
    clk->hse_ok = 0;
    if (RCC_CR == 0u) {
        /* On silicon RCC_CR is never 0 (HSITRIM resets to 16, and some oscillator is on). Reading 0
         * means the RCC is not modelled: QEMU's netduinoplus2 runs at a fixed 168 MHz. */
        clk->emulated = 1;
        clk->sysclk_hz = SYSCLK_TARGET_HZ;
        clk->pclk1_hz = SYSCLK_TARGET_HZ / 4u;
        clk->pclk2_hz = SYSCLK_TARGET_HZ / 2u;
        return;
    }
    if ((RCC_CFGR & RCC_CFGR_SWS_MASK) == RCC_CFGR_SWS_PLL) {
        /* A bootloader (the Crazyflie's) already runs us from the PLL: keep its set-up. */
        clocks_from_registers(clk);
        clk->hse_ok = (RCC_PLLCFGR & RCC_PLLCFGR_SRC_HSE) != 0u;
        return;
    }
    RCC_CR |= RCC_CR_HSEON;
    if (wait_set(&RCC_CR, RCC_CR_HSERDY, RCC_CR_HSERDY)) {
        RCC_CR &= ~RCC_CR_PLLON; /* PLLCFGR may only change while the PLL is off */
        RCC_PLLCFGR = pll_m | (pll_n << 6) | (((pll_p / 2u) - 1u) << 16) | RCC_PLLCFGR_SRC_HSE | (pll_q << 24);
        RCC_CR |= RCC_CR_PLLON;
        if (wait_set(&RCC_CR, RCC_CR_PLLRDY, RCC_CR_PLLRDY)) {
            /* 5 wait states at 168 MHz / 3.3 V, prefetch and ART instruction/data caches on,
             * before the switch; APB1 = /4 (42 MHz max), APB2 = /2 (84 MHz max). */
            FLASH_ACR = FLASH_ACR_LATENCY_5WS | FLASH_ACR_PRFTEN | FLASH_ACR_ICEN | FLASH_ACR_DCEN;
            RCC_CFGR = (RCC_CFGR & ~0xFCF0u) | RCC_CFGR_PPRE1_DIV4 | RCC_CFGR_PPRE2_DIV2;
            RCC_CFGR = (RCC_CFGR & ~3u) | RCC_CFGR_SW_PLL;
            clk->hse_ok = (uint8_t)wait_set(&RCC_CFGR, RCC_CFGR_SWS_MASK, RCC_CFGR_SWS_PLL);
        }
    } else {
        RCC_CR &= ~RCC_CR_HSEON; /* no crystal: stay on the 16 MHz HSI */
    }
    clocks_from_registers(clk);
}

/* ------------------------------------------------------------------------------ cost clock */
static int use_dwt;
volatile uint32_t *platform_cost_counter = &TIM2_CNT;
volatile uint32_t platform_isr_ticks;
static uint32_t dwt_last_cycles;
static uint64_t dwt_total_cycles;
static uint32_t ns_per_cycle_q16; /* 1e9 / sysclk in Q16.16 */

static int dwt_start(void)
{
    uint32_t a, b;
    unsigned i;
    DEMCR |= DEMCR_TRCENA;
    DWT_LAR = 0xC5ACCE55u; /* unlock where a lock is implemented (harmless elsewhere) */
    DWT_CYCCNT = 0u;
    DWT_CTRL |= DWT_CTRL_CYCCNTENA;
    a = DWT_CYCCNT;
    for (i = 0; i < 16u; i++) {
        __asm__ volatile("nop");
    }
    b = DWT_CYCCNT;
    return b != a;
}

void platform_stm32_init(const board_clocks_t *clk)
{
    /* TIM2: free-running 32-bit up-counter, no prescaler. On silicon it counts APB1 timer ticks
     * (84 MHz); under QEMU it counts 1 GHz virtual time = instructions with -icount shift=0. */
    RCC_APB1ENR |= RCC_APB1ENR_TIM2;
    TIM2_CR1 = 0u;
    TIM2_PSC = 0u;
    TIM2_ARR = 0xFFFFFFFFu;
    TIM2_EGR = TIM_EGR_UG; /* load PSC */
    TIM2_CR1 = TIM_CR1_CEN;

    use_dwt = clk->emulated ? 0 : dwt_start();
    platform_cost_counter = use_dwt ? &DWT_CYCCNT : &TIM2_CNT;
    platform_isr_ticks = 0u;
    if (use_dwt) {
        ns_per_cycle_q16 = (uint32_t)((1000000000ull << 16) / clk->sysclk_hz);
        dwt_last_cycles = DWT_CYCCNT - platform_isr_ticks;
        dwt_total_cycles = 0u;
    }
}

int platform_stm32_has_dwt(void) { return use_dwt; }

/* The raw counter minus the ticks interrupts took: the cost of the main thread's own work, so a
 * stage costs the same instructions whether or not link bytes arrived while it ran. Interrupts are
 * masked for the two reads (3 instructions), which keeps the count itself constant. */
static inline uint32_t main_thread_ticks(void)
{
    uint32_t c, isr;
    cpu_irq_disable();
    c = *platform_cost_counter;
    isr = platform_isr_ticks;
    cpu_irq_enable();
    return c - isr;
}

uint32_t platform_cost_now(void)
{
    if (use_dwt) {
        /* Accumulate cycle deltas in 64 bits (CYCCNT wraps every 25.6 s at 168 MHz; the estimator
         * calls this far more often), then scale to ns: the result wraps at 2^32 ns consistently. */
        uint32_t now = main_thread_ticks();
        dwt_total_cycles += (uint32_t)(now - dwt_last_cycles);
        dwt_last_cycles = now;
        return (uint32_t)((dwt_total_cycles * ns_per_cycle_q16) >> 16);
    }
    return main_thread_ticks();
}

uint8_t platform_cost_unit(void)
{
    return (uint8_t)(use_dwt ? PLATFORM_COST_NANOSECONDS : PLATFORM_COST_INSTRUCTIONS);
}

/* ------------------------------------------------------------------------------ C library hooks */
/* newlib's libm wrappers (asinf, atan2f, ...) report domain errors through __errno(). Its libc
 * version returns a field of the 1 KiB re-entrancy structure (_impure_ptr), which would then be
 * linked into .data. The firmware is single threaded and never reads errno: one int does. */
int *__errno(void);
int *__errno(void)
{
    static int errno_value;
    return &errno_value;
}
