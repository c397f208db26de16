/* dense_relu_m4: one hidden layer of the bias network on the Cortex-M4F (FPv4-SP).
 *
 *   void dense_relu_m4(const float *x, unsigned n_in, const float *w, const float *b, float *out);
 *   out[j] = max(0, b[j] + sum_i x[i] * w[i*50 + j])   for j < 50   (w input-major, n_in x 50)
 *
 * Outputs are produced in 5 blocks of 10 accumulators held in s0-s9. For each input, one VLDM
 * brings the 10 contiguous weights of the block into s16-s25 and 10 independent VFMA.F32 follow,
 * so a multiply-add costs ~1.35 instructions (the compiled C loop needs one VLDR per weight).
 * Inputs are consumed two at a time (loop unrolled by 2). Accumulation order per output is
 * bias, then x[0], x[1], ... - a sequential fused dot product. ReLU is done on the integer bits
 * (v & ~(v >> 31) clears negative floats) two outputs at a time while storing.
 * AAPCS: s16-s25 and r4-r8 are callee-saved and restored.
 */
    .syntax unified
    .cpu cortex-m4
    .fpu fpv4-sp-d16
    .thumb

/* acc10 X: s0-s9 += s16-s25 * X (the 10 accumulators of a block, one input) */
    .macro acc10 x
    vfma.f32    s0, s16, \x
    vfma.f32    s1, s17, \x
    vfma.f32    s2, s18, \x
    vfma.f32    s3, s19, \x
    vfma.f32    s4, s20, \x
    vfma.f32    s5, s21, \x
    vfma.f32    s6, s22, \x
    vfma.f32    s7, s23, \x
    vfma.f32    s8, s24, \x
    vfma.f32    s9, s25, \x
    .endm

/* relu2 A, B: store max(0, A), max(0, B) to [r4], r4 += 8 (ReLU on the integer bits) */
    .macro relu2 a, b
    vmov        ip, lr, \a, \b
    bic         ip, ip, ip, asr #31
    bic         lr, lr, lr, asr #31
    strd        ip, lr, [r4], #8
    .endm

    .section .text.dense_relu_m4,"ax",%progbits
    .global dense_relu_m4
    .type dense_relu_m4, %function
    .thumb_func
    .align 2
dense_relu_m4:
    push        {r4-r8, lr}
    vpush       {s16-s25}
    ldr         r4, [sp, #64]           @ out (5th argument; 24 + 40 bytes pushed)
    movs        r5, #5                  @ 5 blocks x 10 outputs = 50
1:  vldmia      r3!, {s0-s9}           @ accumulators = bias block
    mov         r6, r0                  @ x cursor
    mov         r7, r2                  @ weight cursor: w + block offset
    lsrs        r8, r1, #1              @ input pairs
    beq         3f
2:  vldmia      r6!, {s10-s11}         @ x[i], x[i+1]
    vldm        r7, {s16-s25}           @ w[i][block]
    add         r7, r7, #200
    acc10       s10
    vldm        r7, {s16-s25}           @ w[i+1][block]
    add         r7, r7, #200
    acc10       s11
    subs        r8, r8, #1
    bne         2b
3:  tst         r1, #1                  @ odd input count: one more
    beq         4f
    vldmia      r6!, {s10}
    vldm        r7, {s16-s25}
    acc10       s10
4:
    relu2       s0, s1
    relu2       s2, s3
    relu2       s4, s5
    relu2       s6, s7
    relu2       s8, s9
    adds        r2, r2, #40             @ next block of 10 columns
    subs        r5, r5, #1
    bne         1b
    vpop        {s16-s25}
    pop         {r4-r8, pc}
    .size dense_relu_m4, .-dense_relu_m4
