/* TDoA measurement model: h(x) = |p - b| - |p - a| (anchor A = reference, B = the other),
 * H = [(p - b)^T/|p - b| - (p - a)^T/|p - a|, 0 ... 0]. */
#ifndef UWB_MM_TDOA_H
#define UWB_MM_TDOA_H

#include "mm_kinds.h"

/* Predicted distance difference *h and the nonzero part H[0..2] of the Jacobian.
 * Returns MM_OK, or MM_DEGENERATE if the tag is on either anchor or the two anchors coincide
 * (then h = 0 and H = 0 identically: the measurement carries no information). */
int mm_tdoa(const float p[3], const float anchor_a[3], const float anchor_b[3], float *h, float H[3]);

#endif
