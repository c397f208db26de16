/* Quaternion and attitude-error helpers of the EKF (ekf_core.c, ekf_predict.c): inline, as they were when
 * one file held them, so the prediction and the finalize step compile as before. */
#ifndef UWB_EKF_QUAT_H
#define UWB_EKF_QUAT_H

#include <math.h>

#include "trig.h"

static inline void quat_to_rot(const float q[4], float R[3][3])
{
    const float w = q[0], x = q[1], y = q[2], z = q[3];
    R[0][0] = w * w + x * x - y * y - z * z;
    R[0][1] = 2.0f * (x * y - w * z);
    R[0][2] = 2.0f * (x * z + w * y);
    R[1][0] = 2.0f * (x * y + w * z);
    R[1][1] = w * w - x * x + y * y - z * z;
    R[1][2] = 2.0f * (y * z - w * x);
    R[2][0] = 2.0f * (x * z - w * y);
    R[2][1] = 2.0f * (y * z + w * x);
    R[2][2] = w * w - x * x - y * y + z * z;
}

/* q <- normalise(q (x) exp(v)), v a body-frame rotation vector [rad]. */
static inline void quat_rotate_body(float q[4], const float v[3])
{
    const float theta = sqrtf(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    /* sin(theta/2)/theta -> 1/2 as theta -> 0: avoid 0/0 for tiny rotations. */
    const float s = theta > 1e-6f ? trig_sinf(0.5f * theta) / theta : 0.5f;
    const float dw = trig_cosf(0.5f * theta), dx = s * v[0], dy = s * v[1], dz = s * v[2];
    const float w = q[0], x = q[1], y = q[2], z = q[3];
    float n;
    q[0] = w * dw - x * dx - y * dy - z * dz;
    q[1] = w * dx + x * dw + y * dz - z * dy;
    q[2] = w * dy - x * dz + y * dw + z * dx;
    q[3] = w * dz + x * dy - y * dx + z * dw;
    n = sqrtf(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    q[0] /= n;
    q[1] /= n;
    q[2] /= n;
    q[3] /= n;
}

/* Second-order rotation of the attitude-error covariance for a half-angle vector d (reference). */
static inline void att_block(const float d[3], float G[3][3])
{
    G[0][0] = 1.0f - 0.5f * d[1] * d[1] - 0.5f * d[2] * d[2];
    G[0][1] = d[2] + 0.5f * d[0] * d[1];
    G[0][2] = -d[1] + 0.5f * d[0] * d[2];
    G[1][0] = -d[2] + 0.5f * d[0] * d[1];
    G[1][1] = 1.0f - 0.5f * d[0] * d[0] - 0.5f * d[2] * d[2];
    G[1][2] = d[0] + 0.5f * d[1] * d[2];
    G[2][0] = d[1] + 0.5f * d[0] * d[2];
    G[2][1] = -d[0] + 0.5f * d[1] * d[2];
    G[2][2] = 1.0f - 0.5f * d[0] * d[0] - 0.5f * d[1] * d[1];
}

#endif
