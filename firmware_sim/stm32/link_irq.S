/* The link USART's interrupt vector: runs link_rx_isr() and adds the ticks it took to
 * platform_isr_ticks (platform_stm32.c), which platform_cost_now() subtracts.
 *
 * Under QEMU -icount a counter read returns the number of instructions executed before it. The
 * wrapper reads the counter (t0) as its 3rd instruction and again (t1) 8 instructions before its end:
 * the interrupt's whole length is (t1 - t0) + 2 (the instructions before t0) + 8 (the t1 load and the
 * 7 after it), hence ISR_UNCOUNTED = 10 (checked by tests/mcu/test_qemu.py with the self-test ELF). Exception entry is not an instruction. On silicon (DWT cycles)
 * the 12-cycle entry and the wrapper's few outer cycles are not subtracted: interrupt time is removed
 * to within ~20 cycles per interrupt there. */
#if UWB_USART == 1
#define LINK_VECTOR USART1_IRQHandler
#elif UWB_USART == 3
#define LINK_VECTOR USART3_IRQHandler
#else
#error "UWB_USART must be 1 or 3"
#endif
#define ISR_UNCOUNTED 10

    .syntax unified
    .cpu cortex-m4
    .thumb
    .section .text.link_vector,"ax",%progbits
    .global LINK_VECTOR
    .type LINK_VECTOR, %function
    .thumb_func
    .align 2
LINK_VECTOR:
    ldr         r0, =platform_cost_counter
    ldr         r1, [r0]                @ r1 = &counter
    ldr         r1, [r1]                @ t0
    push        {r0, r1, r2, lr}
    bl          link_rx_isr
    pop         {r0, r1, r2, lr}
    ldr         r2, [r0]                @ &counter
    ldr         r2, [r2]                @ t1 (then 7 more instructions)
    ldr         r3, =platform_isr_ticks
    subs        r2, r2, r1
    ldr         r1, [r3]
    adds        r2, r2, #ISR_UNCOUNTED
    add         r1, r1, r2
    str         r1, [r3]
    bx          lr
    .ltorg
    .size LINK_VECTOR, .-LINK_VECTOR
