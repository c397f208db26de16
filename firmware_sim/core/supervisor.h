/* The estimator's supervisor: after every prediction and every fused update, a state that is not finite,
 * outside the anchors' box, too fast or too uncertain restarts the filter (supervisor.c). */
#ifndef UWB_SUPERVISOR_H
#define UWB_SUPERVISOR_H

#include "estimator.h"

/* Check the state; on a failing check restart the filter and set est->flags (DIVERGED | reason, or
 * GAP_RESTART) and the counters; a passing state becomes the last good position. */
void estimator_supervise(estimator_t *est);

#endif
