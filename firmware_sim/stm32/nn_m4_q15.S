/* The q15 bias network's sums on the Cortex-M4 with SMLAD (bias_nn.h: the q15 form; bias_nn_q15.c is the
 * portable reference, with the same integers).
 *
 *   void q15_dense_m4(const int16_t *x, unsigned n_pairs, const int16_t *w, const int32_t *b, int16_t *out,
 *                     unsigned shift);
 *   out[j] = clamp((b[j] + sum_k x[2k] w[2k][j] + x[2k+1] w[2k+1][j]) >> shift, 0, 32767), j < 50
 *
 *   void q15_sparse_m4(const uint32_t *list, const int16_t *w, const int32_t *b, int16_t *out, unsigned shift);
 *   the same for the 50-input layer over the input pairs listed: (x[2k], x[2k+1]) as one word and the byte
 *   offset 20 k of pair k in block 0, one entry per pair with a nonzero input, ended by a zero word. ReLU
 *   leaves most of the first hidden layer at 0 (a third of the pairs nonzero on the simulated flights);
 *   a pair of zeros adds nothing to any sum, so leaving it out gives the same integers.
 *
 *   void q15_heads2_m4(const int16_t *x, unsigned n_pairs, const int16_t *w, int32_t acc2[2]);
 *   acc2[t] += sum_k x[2k] w[2k][t] + x[2k+1] w[2k+1][t], t < 2   (acc2 holds the biases on entry)
 *   void q15_head0_m4(const int16_t *x, unsigned n_pairs, const int16_t *w, int32_t *acc);
 *   the same for t = 0 only (the bias; the std head is not wanted), n_pairs a multiple of 5
 *
 * w is the layer's block-major table (bias_nn.h): block t (outputs 5t..5t+4) holds, for each pair k, its
 * five words, so one LDM fetches them; the next block follows (20 n_pairs bytes on). Per pair: the pair's
 * word, one LDM, one SMLAD per output (two 16 x 16 multiply-adds each). The ten blocks run in one call,
 * their sums in r4-r8; the dense pair loop is unrolled by five when n_pairs allows. The sums are exact
 * int32 (the exporter's bound: no overflow for any input). ReLU + requantisation: an arithmetic shift,
 * then USAT to [0, 32767]. AAPCS: r4-r11 saved; n_pairs >= 1.
 */
    .syntax unified
    .cpu cortex-m4
    .thumb

    .equ BLOCKS, 10                 @ BIAS_NN_HIDDEN / 5
    .equ SPARSE_STRIDE, 500         @ bytes of one block of a 50-input layer: 25 pairs x 5 words
    @ locals above sp: x or list, biases, out, shift, blocks left, pair-loop count, unrolled?
    .equ L_X, 0
    .equ L_B, 4
    .equ L_OUT, 8
    .equ L_SHIFT, 12
    .equ L_LEFT, 16
    .equ L_COUNT, 20
    .equ L_UNROLLED, 24
    .equ FRAME, 32
    .equ ARG5, FRAME + 36           @ the 5th argument, above the locals and the 9 saved registers
    .equ ARG6, FRAME + 40

    .macro smlad5                   @ the five sums r4-r8 += pair word r3 . weight words r9-r12, lr
    smlad   r4, r3, r9, r4
    smlad   r5, r3, r10, r5
    smlad   r6, r3, r11, r6
    smlad   r7, r3, r12, r7
    smlad   r8, r3, lr, r8
    .endm

    .macro pair5                    @ x pair word r3 from r0, five weight words from r2
    ldr     r3, [r0], #4
    ldmia   r2!, {r9-r12, lr}
    smlad5
    .endm

    .macro listed done              @ one entry of the list at r0 into the block at r2; zero word -> done
    ldrd    r3, r1, [r0], #8
    cbz     r3, \done
    add     r1, r1, r2
    ldm     r1, {r9-r12, lr}
    smlad5
    .endm

    .macro begin_block              @ r4-r8 <- the block's five biases
    ldr     r3, [sp, #L_B]
    ldmia   r3!, {r4-r8}
    str     r3, [sp, #L_B]
    .endm

    .macro end_block again          @ ReLU, requantise, store the five outputs; next block
    ldr     r0, [sp, #L_OUT]
    ldr     r1, [sp, #L_SHIFT]
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
    strh    r4, [r0], #2
    strh    r5, [r0], #2
    strh    r6, [r0], #2
    strh    r7, [r0], #2
    strh    r8, [r0], #2
    str     r0, [sp, #L_OUT]
    ldr     r1, [sp, #L_LEFT]
    subs    r1, r1, #1
    str     r1, [sp, #L_LEFT]
    bne     \again
    .endm

    .macro enter_layer b           @ save r4-r11, lr; locals: x (or the list) from r0, the biases, ten blocks
    push    {r4-r11, lr}
    sub     sp, sp, #FRAME
    str     r0, [sp, #L_X]
    str     \b, [sp, #L_B]
    movs    r0, #BLOCKS
    str     r0, [sp, #L_LEFT]
    .endm

    .macro function name           @ a global Thumb function's label
    .align 2
    .global \name
    .type \name, %function
    .thumb_func
\name:
    .endm

    .text
    function q15_dense_m4
    enter_layer r3
    ldr     r4, [sp, #ARG5]
    ldr     r5, [sp, #ARG6]
    str     r4, [sp, #L_OUT]
    str     r5, [sp, #L_SHIFT]
    movs    r9, #5
    udiv    r10, r1, r9             @ n_pairs / 5
    mls     r9, r10, r9, r1         @ n_pairs % 5
    cmp     r9, #0
    ite     eq
    moveq   r4, #1                  @ unrolled by five: n_pairs / 5 iterations
    movne   r4, #0                  @ one pair per iteration: n_pairs iterations
    it      eq
    moveq   r1, r10
    str     r1, [sp, #L_COUNT]
    str     r4, [sp, #L_UNROLLED]
1:  begin_block
    ldr     r0, [sp, #L_X]
    ldr     r1, [sp, #L_COUNT]
    ldr     r3, [sp, #L_UNROLLED]
    cmp     r3, #0
    beq     3f
2:  pair5                           @ five pairs per iteration
    pair5
    pair5
    pair5
    pair5
    subs    r1, r1, #1
    bne     2b
    b       4f
3:  pair5                           @ one pair per iteration
    subs    r1, r1, #1
    bne     3b
4:  end_block 1b                    @ w (r2) is at the next block already
    add     sp, sp, #FRAME
    pop     {r4-r11, pc}
    .size q15_dense_m4, .-q15_dense_m4

    function q15_sparse_m4
    enter_layer r2
    ldr     r4, [sp, #ARG5]
    str     r3, [sp, #L_OUT]
    str     r4, [sp, #L_SHIFT]
    mov     r2, r1                  @ block 0
1:  begin_block
    ldr     r0, [sp, #L_X]          @ the list from its start
2:  listed  3f                      @ two entries per iteration
    listed  3f
    b       2b
3:  add     r2, r2, #SPARSE_STRIDE  @ the next block's table
    end_block 1b
    add     sp, sp, #FRAME
    pop     {r4-r11, pc}
    .size q15_sparse_m4, .-q15_sparse_m4

    function q15_heads2_m4
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

    function q15_head0_m4                       @ the bias head alone of a two-head table (its words 8 bytes apart)
    push    {r4-r6, lr}
    ldr     r4, [r3]
1:  .rept 5
    ldr     r5, [r0], #4
    ldr     r6, [r2], #8
    smlad   r4, r5, r6, r4
    .endr
    subs    r1, r1, #5
    bne     1b
    str     r4, [r3]
    pop     {r4-r6, pc}
    .size q15_head0_m4, .-q15_head0_m4

