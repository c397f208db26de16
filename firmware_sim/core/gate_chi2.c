/* Chi-square gate (ARCHITECTURE.md, pipeline step 4). */
#include "gate_chi2.h"

int gate_chi2_pass(float innovation, float S, float threshold)
{
    /* Written so that NaN fails the gate. */
    return innovation * innovation / S <= threshold;
}

int gate_chi2_reopened(int64_t rejected_us)
{
    return rejected_us > GATE_CHI2_REOPEN_US;
}
