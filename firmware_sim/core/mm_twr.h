/* TWR measurement model: h(x) = |p - a|, H = [(p - a)^T / h, 0 ... 0]. */
#ifndef UWB_MM_TWR_H
#define UWB_MM_TWR_H

#include "mm_kinds.h"

/* Predicted range *h and the nonzero part H[0..2] of the Jacobian for tag position p and anchor a.
 * Returns MM_OK, or MM_DEGENERATE (tag on the anchor; *h and H are then 0). */
int mm_twr(const float p[3], const float anchor[3], float *h, float H[3]);

#endif
