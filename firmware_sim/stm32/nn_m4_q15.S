/* The q15 bias network's sums on the Cortex-M4 with SMLAD (bias_nn.h: the q15 form; bias_nn_q15.c is the
 * portable reference, with the same integers).
 *
 *   void q15_block5_m4(const int16_t *x, unsigned n_pairs, const int16_t *w, const int32_t *b5,
 *                      int16_t *out5, unsigned shift);
 *   out5[t] = clamp((b5[t] + sum_k x[2k] w[2k][t] + x[2k+1] w[2k+1][t]) >> shift, 0, 32767), t < 5
 *
 *   void q15_heads2_m4(const int16_t *x, unsigned n_pairs, const int16_t *w, int32_t acc2[2]);
 *   acc2[t] += sum_k x[2k] w[2k][t] + x[2k+1] w[2k+1][t], t < 2   (acc2 holds the biases on entry)
 *
 * w points at the block's words in the block-major layout (bias_nn.h): pair k's words of the block's
 * outputs are contiguous and the next pair's follow, so one LDM with write-back fetches them. Per pair:
 * one LDR of (x[2k], x[2k+1]), one LDM, one SMLAD per output (two 16 x 16 multiply-adds each); the pair
 * loop is unrolled by five when n_pairs allows (25 for the second layer, 5 for 9 inputs). The sums are
 * exact int32 (the exporter's bound: no overflow for any input). ReLU + requantisation: an arithmetic
 * shift, then USAT to [0, 32767]. AAPCS: r4-r11 saved; n_pairs >= 1.
 */
    .syntax unified
    .cpu cortex-m4
    .thumb

    .macro pair5
    ldr     r3, [r0], #4
    ldmia   r2!, {r9-r12, lr}
    smlad   r4, r3, r9, r4
    smlad   r5, r3, r10, r5
    smlad   r6, r3, r11, r6
    smlad   r7, r3, r12, r7
    smlad   r8, r3, lr, r8
    .endm

    .text
    .align 2
    .global q15_block5_m4
    .type q15_block5_m4, %function
    .thumb_func
q15_block5_m4:
    push    {r4-r11, lr}
    ldm     r3, {r4-r8}             @ the five biases
    movs    r9, #5
    udiv    r10, r1, r9             @ n_pairs / 5
    mls     r9, r10, r9, r1         @ n_pairs % 5
    cmp     r9, #0
    bne     2f
    mov     r1, r10
1:  pair5                           @ five pairs per iteration
    pair5
    pair5
    pair5
    pair5
    subs    r1, r1, #1
    bne     1b
    b       3f
2:  pair5                           @ one pair per iteration
    subs    r1, r1, #1
    bne     2b
3:  ldr     r0, [sp, #36]           @ out5 (5th argument, above the 9 saved registers)
    ldr     r1, [sp, #40]           @ shift
    asr     r4, r4, r1
    asr     r5, r5, r1
    asr     r6, r6, r1
    asr     r7, r7, r1
    asr     r8, r8, r1
    usat    r4, #15, r4
    usat    r5, #15, r5
    usat    r6, #15, r6
    usat    r7, #15, r7
    usat    r8, #15, r8
    strh    r4, [r0]
    strh    r5, [r0, #2]
    strh    r6, [r0, #4]
    strh    r7, [r0, #6]
    strh    r8, [r0, #8]
    pop     {r4-r11, pc}
    .size q15_block5_m4, .-q15_block5_m4

    .align 2
    .global q15_heads2_m4
    .type q15_heads2_m4, %function
    .thumb_func
q15_heads2_m4:
    push    {r4-r8, lr}
    ldm     r3, {r4, r5}
1:  ldr     r6, [r0], #4
    ldmia   r2!, {r7, r8}
    smlad   r4, r6, r7, r4
    smlad   r5, r6, r8, r5
    subs    r1, r1, #1
    bne     1b
    stm     r3, {r4, r5}
    pop     {r4-r8, pc}
    .size q15_heads2_m4, .-q15_heads2_m4
