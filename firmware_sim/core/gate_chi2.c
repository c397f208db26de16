/* Chi-square gate (ARCHITECTURE.md, pipeline step 4). */
#include "gate_chi2.h"

int gate_chi2_pass(float innovation, float S, float threshold)
{
    /* Written so that NaN fails the gate. */
    return innovation * innovation / S <= threshold;
}
