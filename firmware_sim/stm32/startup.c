/* Reset handler and vector table for the STM32F405 (16 Cortex-M4 exceptions + 82 IRQs).
 * Reset: enable the FPU (CP10/CP11 full access) before any float instruction, copy .data from
 * flash, zero .bss, point VTOR at this table, call main(). Faults report over the link USART. */
#include <stdint.h>

#include "board.h"
#include "stm32f405_regs.h"

/* Linker script symbols (stm32f405.ld). */
extern uint32_t _sidata, _sdata, _edata, _sbss, _ebss, _sstack, _estack;

/* The unused stack is painted with this word at reset; the lowest word that no longer holds it is
 * the high-water mark (read with a debugger, or by the harness through QEMU's monitor). */
#define STACK_PAINT 0xA5A5A5A5u

int main(void);
void Reset_Handler(void);
void Default_Handler(void);
void HardFault_Handler(void);
void fault_report(const uint32_t *frame, uint32_t kind);

/* Every handler not defined elsewhere lands in Default_Handler. */
#define WEAK_DEFAULT __attribute__((weak, alias("Default_Handler")))
void NMI_Handler(void) WEAK_DEFAULT;
void MemManage_Handler(void) WEAK_DEFAULT;
void BusFault_Handler(void) WEAK_DEFAULT;
void UsageFault_Handler(void) WEAK_DEFAULT;
void SVC_Handler(void) WEAK_DEFAULT;
void DebugMon_Handler(void) WEAK_DEFAULT;
void PendSV_Handler(void) WEAK_DEFAULT;
void SysTick_Handler(void) WEAK_DEFAULT;
void TIM2_IRQHandler(void) WEAK_DEFAULT;
void USART1_IRQHandler(void) WEAK_DEFAULT;
void USART3_IRQHandler(void) WEAK_DEFAULT;

#define N_IRQ 82u
typedef void (*vector_t)(void);

/* Index 0 is the initial stack pointer; the rest are handlers. IRQ n sits at 16 + n. Every IRQ
 * slot defaults to Default_Handler (GCC range initialiser), then the named ones override it. */
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Woverride-init"
__attribute__((section(".isr_vector"), used)) const vector_t vector_table[16u + N_IRQ] = {
    [16 ... 16u + N_IRQ - 1u] = Default_Handler,
    [0] = (vector_t)(uintptr_t)&_estack,
    [1] = Reset_Handler,
    [2] = NMI_Handler,
    [3] = HardFault_Handler,
    [4] = MemManage_Handler,
    [5] = BusFault_Handler,
    [6] = UsageFault_Handler,
    [11] = SVC_Handler,
    [12] = DebugMon_Handler,
    [14] = PendSV_Handler,
    [15] = SysTick_Handler,
    [16u + 28u] = TIM2_IRQHandler,
    [16u + USART1_IRQn] = USART1_IRQHandler,
    [16u + USART3_IRQn] = USART3_IRQHandler,
};
#pragma GCC diagnostic pop

void Reset_Handler(void)
{
    uint32_t *src, *dst, *sp;

    SCB_CPACR |= 0xFu << 20; /* CP10 + CP11 full access: hard-float code may run after this */
    cpu_dsb();
    cpu_isb();
    SCB_VTOR = (uint32_t)(uintptr_t)vector_table; /* also right when linked behind a bootloader */

    for (src = &_sidata, dst = &_sdata; dst < &_edata;) {
        *dst++ = *src++;
    }
    for (dst = &_sbss; dst < &_ebss;) {
        *dst++ = 0u;
    }
    __asm__ volatile("mov %0, sp" : "=r"(sp));
    for (dst = &_sstack; dst < sp - 16; dst++) { /* leave this frame alone */
        *dst = STACK_PAINT;
    }
    (void)main();
    for (;;) {
        cpu_wfi();
    }
}

void Default_Handler(void)
{
    uint32_t ipsr;
    __asm__ volatile("mrs %0, ipsr" : "=r"(ipsr));
    fault_report((const uint32_t *)0, ipsr);
}

/* Pick the stack the exception frame was pushed on and hand it to fault_report(). */
__attribute__((naked)) void HardFault_Handler(void)
{
    __asm__ volatile("tst lr, #4\n"
                     "ite eq\n"
                     "mrseq r0, msp\n"
                     "mrsne r0, psp\n"
                     "movs r1, #3\n"
                     "b fault_report\n");
}

/* Print what is known about the fault between frame delimiters (the host sees one undecodable
 * frame and the text in its log), then stop. kind = exception number. */
void fault_report(const uint32_t *frame, uint32_t kind)
{
    static const uint8_t delim = 0;
    usart_write(&delim, 1);
    usart_puts("FAULT exc=");
    usart_put_hex32(kind);
    if (frame != (const uint32_t *)0) {
        usart_puts(" pc=");
        usart_put_hex32(frame[6]);
        usart_puts(" lr=");
        usart_put_hex32(frame[5]);
    }
    usart_puts(" cfsr=");
    usart_put_hex32(SCB_CFSR);
    usart_puts(" hfsr=");
    usart_put_hex32(SCB_HFSR);
    usart_puts(" bfar=");
    usart_put_hex32(SCB_BFAR);
    usart_puts("\n");
    usart_write(&delim, 1);
    usart_flush();
    cpu_irq_disable();
    for (;;) {
        cpu_wfi();
    }
}
