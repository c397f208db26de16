/* Gates at their boundaries: equality passes, the next float up fails, NaN fails. */
#include <float.h>

#include "gate_chi2.h"
#include "gate_kinematic.h"
#include "unit.h"

static void test_dmax(void)
{
    const float v[3] = {3.0f, 4.0f, 0.0f}, still[3] = {0.0f, 0.0f, 0.0f};
    CHECK_NEAR(gate_kinematic_dmax(v, 0.1f, 10.0f), 5.0 * 0.1 + 0.5 * 10.0 * 0.01, 1e-6);
    CHECK_NEAR(gate_kinematic_dmax(still, 0.01f, 5000.0f), 0.25, 1e-6);
}

static void test_dt(void)
{
    CHECK_NEAR(gate_kinematic_dt(0, 0, 0.01f), 0.01, 1e-9);       /* no reference time yet */
    CHECK_NEAR(gate_kinematic_dt(123456, 0, 0.01f), 0.01, 1e-9);  /* ignored without reference */
    CHECK_NEAR(gate_kinematic_dt(5000, 1, 0.01f), 0.01, 1e-9);    /* floored */
    CHECK_NEAR(gate_kinematic_dt(0, 1, 0.01f), 0.01, 1e-9);       /* the paper code's dt = 0 case */
    CHECK_NEAR(gate_kinematic_dt(-5000, 1, 0.01f), 0.01, 1e-9);   /* reference after the measurement */
    CHECK_NEAR(gate_kinematic_dt(20000, 1, 0.01f), 0.02, 1e-9);
}

/* The window's state: from the last fusion while measurements are rejected, plus the time a link's
 * anchors have been rejected; an isolated outlier meets the nominal bound. */
static void test_window_state(void)
{
    gate_kinematic_t g;
    gate_kinematic_reset(&g);
    CHECK_NEAR(gate_kinematic_window(&g, 1000, 0, 0, 0, 0, 0.01f, 1), 0.01, 1e-9);          /* no reference */
    CHECK_NEAR(gate_kinematic_window(&g, 20000, 1, 1, 15000, 1, 0.01f, 1), 0.01, 1e-9);     /* 5 ms, floored */
    gate_kinematic_fused(&g, 20000, 1, 1); /* first fusion: every anchor's clock starts */
    CHECK(g.has_fused && g.t_anchor_fused_us[7] == 20000);
    /* 1 s without fusion: counted from the last fusion, not from the fresh reference */
    CHECK_NEAR(gate_kinematic_window(&g, 1020000, 1, 1, 1015000, 1, 0.01f, 1), 1.0, 1e-6);
    gate_kinematic_fused(&g, 1020000, 2, 2); /* anchor 2 fused, anchor 1 (measured at 1.02 s) was not */
    CHECK_NEAR(gate_kinematic_window(&g, 1030000, 2, 2, 1025000, 1, 0.01f, 1), 0.01, 1e-9);
    CHECK(g.rejected_us == 0);
    /* anchor 1: 20 ms since the last fusion + 1 s its links had been rejected */
    CHECK_NEAR(gate_kinematic_window(&g, 1040000, 1, 1, 1035000, 1, 0.01f, 1), 1.02, 1e-6);
    CHECK(g.rejected_us == 1000000); /* what the chi-square gate's guard sees */
    /* TDoA (2, 1): the longer rejection of the two */
    CHECK_NEAR(gate_kinematic_window(&g, 1050000, 2, 1, 1045000, 1, 0.01f, 1), 1.05, 1e-6);
    gate_kinematic_fused(&g, 1050000, 2, 1);
    CHECK_NEAR(gate_kinematic_window(&g, 1060000, 1, 1, 1055000, 1, 0.01f, 1), 0.01, 1e-9); /* nominal again */
    CHECK_NEAR(gate_kinematic_window(&g, 1070000, 200, 3, 1065000, 1, 0.01f, 1), 0.02, 1e-6); /* bad id: no state */
    gate_kinematic_reset(&g);
    CHECK(!g.has_fused && g.t_anchor_seen_us[1] == 0 && g.t_anchor_fused_us[1] == 0);
}

static void test_kinematic_boundary(void)
{
    const float d = 0.25f;
    CHECK(gate_kinematic_pass(0.25f, d, 1.0f));
    CHECK(gate_kinematic_pass(-0.25f, d, 1.0f));
    CHECK(!gate_kinematic_pass(nextafterf(0.25f, 1.0f), d, 1.0f));
    CHECK(!gate_kinematic_pass(-nextafterf(0.25f, 1.0f), d, 1.0f));
    /* TDoA: twice the bound */
    CHECK(gate_kinematic_pass(0.5f, d, 2.0f));
    CHECK(!gate_kinematic_pass(nextafterf(0.5f, 1.0f), d, 2.0f));
    CHECK(!gate_kinematic_pass(NAN, d, 1.0f));
    CHECK(gate_kinematic_pass(0.0f, 0.0f, 1.0f));
}

static void test_chi2_boundary(void)
{
    CHECK(gate_chi2_pass(2.0f, 1.0f, 4.0f));                     /* y^2/S = 4 = threshold */
    CHECK(gate_chi2_pass(-2.0f, 1.0f, 4.0f));
    CHECK(!gate_chi2_pass(2.0f, 1.0f, nextafterf(4.0f, 0.0f)));
    CHECK(!gate_chi2_pass(nextafterf(2.0f, 3.0f), 1.0f, 4.0f));
    CHECK(gate_chi2_pass(0.5f, 0.0625f, 4.0f));                  /* 0.25/0.0625 = 4 exactly */
    CHECK(!gate_chi2_pass(0.5f, nextafterf(0.0625f, 0.0f), 4.0f));
    CHECK(!gate_chi2_pass(NAN, 1.0f, 4.0f));
    CHECK(!gate_chi2_pass(1.0f, NAN, 4.0f));
    CHECK(!gate_chi2_pass(1.0f, 1.0f, NAN));
}

/* The chi-square gate's lock-out guard: open only beyond GATE_CHI2_REOPEN_US of rejection. */
static void test_chi2_reopen(void)
{
    CHECK(!gate_chi2_reopened(0));
    CHECK(!gate_chi2_reopened(-1000000));
    CHECK(!gate_chi2_reopened(GATE_CHI2_REOPEN_US));
    CHECK(gate_chi2_reopened(GATE_CHI2_REOPEN_US + 1));
    CHECK(gate_chi2_reopened(INT64_MAX));
}

int main(void)
{
    RUN(test_dmax);
    RUN(test_dt);
    RUN(test_window_state);
    RUN(test_kinematic_boundary);
    RUN(test_chi2_boundary);
    RUN(test_chi2_reopen);
    return UNIT_DONE();
}
