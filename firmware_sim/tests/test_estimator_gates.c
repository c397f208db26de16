/* estimator: statuses and gates in the pipeline (geometry, kinematic, chi-square and its lock-out guard,
 * the gates' time references) and the robust update. */
#include <string.h>

#include "estimator_fixture.h"
#include "mm_table.h"
#include "robust_update.h"

static void test_statuses(void)
{
    estimator_result_t r;
    ekf_t before;
    const float p0[3] = {0.0f, 0.0f, 1.0f};
    const float on_tag[3] = {0.0f, 0.0f, 1.0f};
    float h;

    /* geometry: an anchor exactly at the estimate */
    setup(EST_MODE_IMU, EST_STAGES_ALL, p0[0], p0[1], p0[2]);
    CHECK(estimator_set_anchor(&est, 9, on_tag) == EST_OK);
    memcpy(&before, &est.ekf, sizeof before);
    CHECK(estimator_on_twr(&est, 1000, 9, 0.5f, &r) == EST_OK);
    CHECK(r.status == EST_REJECTED_GEOMETRY);
    CHECK(r.innovation == 0.0f && r.innovation_var == 0.0f && r.gain[0] == 0.0f);
    CHECK_NEAR(r.d_max, 0.25, 1e-6); /* at rest, dt_min = 10 ms, a_max 5000 */
    CHECK(memcmp(&before, &est.ekf, sizeof before) == 0);
    CHECK(estimator_on_tdoa(&est, 1000, 9, 9, 0.0f, &r) == EST_OK && r.status == EST_REJECTED_GEOMETRY);
    CHECK(estimator_on_tdoa(&est, 1000, 0, 9, 0.0f, &r) == EST_OK && r.status == EST_REJECTED_GEOMETRY);

    /* kinematic: rejected when |y| > d_max = 0.25 m (at rest); 0.2 m passes */
    h = range_to(&est, 0, p0);
    CHECK(estimator_on_twr(&est, 2000, 0, h + 0.3f, &r) == EST_OK);
    CHECK(r.status == EST_REJECTED_KINEMATIC);
    CHECK_NEAR(r.innovation, 0.3, 1e-5);
    CHECK(r.innovation_var > 0.0625f && r.gain[0] == 0.0f && r.gain[1] == 0.0f && r.gain[2] == 0.0f);
    CHECK(memcmp(&before, &est.ekf, sizeof before) == 0);
    CHECK(estimator_on_twr(&est, 2000, 0, h + 0.2f, &r) == EST_OK);
    CHECK(r.status == EST_ACCEPTED && r.gain[0] != 0.0f);
    /* TDoA: twice the bound */
    {
        const float d = range_to(&est, 1, est.last_good_pos) - range_to(&est, 0, est.last_good_pos);
        CHECK(estimator_on_tdoa(&est, 3000, 0, 1, d + 0.55f, &r) == EST_OK);
        CHECK(r.status == EST_REJECTED_KINEMATIC);
        CHECK_NEAR(r.innovation, 0.55, 1e-5);
        CHECK(estimator_on_tdoa(&est, 3000, 0, 1, d + 0.45f, &r) == EST_OK);
        CHECK_NEAR(r.innovation, 0.45, 1e-5);
        CHECK(r.status != EST_REJECTED_KINEMATIC);
    }

    /* chi-square only: big innovations pass the (disabled) kinematic gate but not y^2/S */
    setup(EST_MODE_IMU, EST_STAGE_CHI2_GATE, p0[0], p0[1], p0[2]);
    h = range_to(&est, 0, p0);
    CHECK(estimator_on_twr(&est, 1000, 0, h + 3.0f, &r) == EST_OK);
    CHECK(r.status == EST_REJECTED_CHI2);
    CHECK(r.innovation * r.innovation / r.innovation_var > est.cfg.chi2_twr);
    CHECK_NEAR(r.d_max, 0.25, 1e-6); /* reported although the gate is off */
    CHECK(estimator_on_twr(&est, 1000, 0, h + 1.0f, &r) == EST_OK);
    CHECK(r.status == EST_ACCEPTED);
    CHECK(r.innovation * r.innovation / r.innovation_var <= est.cfg.chi2_twr);

    /* no gates: anything finite is used */
    setup(EST_MODE_IMU, 0, p0[0], p0[1], p0[2]);
    CHECK(estimator_on_twr(&est, 1000, 0, h + 3.0f, &r) == EST_OK);
    CHECK(r.status == EST_ACCEPTED);
}

/* The chi-square gate cannot lock an anchor out: with a sustained 1 m offset on anchor 0 (the others
 * exact, round robin every 10 ms) its ranges are rejected until its links have been rejected for longer
 * than GATE_CHI2_REOPEN_US, then let through; an isolated outlier is rejected. */
static void test_chi2_lockout_guard(void)
{
    estimator_result_t r;
    const float p0[3] = {0.5f, -0.5f, 1.0f};
    uint64_t t = 10000;
    int k, rejected = 0, first_accept = -1;
    setup(EST_MODE_IMU, EST_STAGE_CHI2_GATE, p0[0], p0[1], p0[2]);
    for (k = 0; k < 80; k++, t += 10000) { /* converge on exact ranges */
        CHECK(estimator_on_twr(&est, t, (uint8_t)(k % 8), range_to(&est, (uint8_t)(k % 8), p0), &r) == EST_OK);
        CHECK(r.status == EST_ACCEPTED);
    }
    CHECK(estimator_on_twr(&est, t, 0, range_to(&est, 0, p0) + 1.0f, &r) == EST_OK); /* isolated */
    CHECK(r.status == EST_REJECTED_CHI2);
    for (k = 1; k < 8; k++) {
        t += 10000;
        CHECK(estimator_on_twr(&est, t, (uint8_t)k, range_to(&est, (uint8_t)k, p0), &r) == EST_OK);
    }
    for (k = 0; k < 6; k++) { /* anchor 0 now every 80 ms, always 1 m long */
        int j;
        t += 10000;
        CHECK(estimator_on_twr(&est, t, 0, range_to(&est, 0, p0) + 1.0f, &r) == EST_OK);
        if (r.status == EST_REJECTED_CHI2 && first_accept < 0) {
            rejected++;
        } else if (r.status == EST_ACCEPTED && first_accept < 0) {
            first_accept = k;
        }
        for (j = 1; j < 8; j++) {
            t += 10000;
            CHECK(estimator_on_twr(&est, t, (uint8_t)j, range_to(&est, (uint8_t)j, p0), &r) == EST_OK);
        }
    }
    /* its links rejected since the isolated outlier (its last fusion 80 ms before it): at its 3rd
     * measurement in the loop they had been for 0.24 s > 0.2 s */
    CHECK(rejected == 2 && first_accept == 2);
}

/* A range to the floor below the TOF row's floor_below (the ranger on the floor, takeoff.h) keeps the lock-out
 * guard closed in any mode: anchor 0's links, 1 m long, stay rejected; readings in the air let them in again. */
static void test_floor_range_keeps_the_guard_closed(void)
{
    estimator_result_t r;
    const float p0[3] = {0.5f, -0.5f, 1.0f};
    const uint8_t none[2] = {0, 0};
    uint64_t t = 10000;
    int k, j, accepted = 0;
    setup(EST_MODE_IMU, EST_STAGE_CHI2_GATE, p0[0], p0[1], p0[2]);
    est.cfg.tof_z = -0.98f; /* the ranger reads 0.02 m at the estimate's height */
    for (k = 0; k < 80; k++, t += 10000) {
        CHECK(estimator_on_twr(&est, t, (uint8_t)(k % 8), range_to(&est, (uint8_t)(k % 8), p0), &r) == EST_OK);
    }
    for (k = 0; k < 12; k++) {
        t += 10000;
        CHECK(estimator_on_meas(&est, MM_KIND_TOF, t, none, k < 6 ? 0.02f : 0.5f, &r) == EST_OK);
        CHECK(k >= 6 || r.status == EST_ACCEPTED);
        t += 10000;
        CHECK(estimator_on_twr(&est, t, 0, range_to(&est, 0, p0) + 1.0f, &r) == EST_OK);
        CHECK(k >= 6 || r.status == EST_REJECTED_CHI2);
        accepted += k >= 6 && r.status == EST_ACCEPTED;
        for (j = 1; j < 8; j++) {
            t += 10000;
            CHECK(estimator_on_twr(&est, t, (uint8_t)j, range_to(&est, (uint8_t)j, p0), &r) == EST_OK);
        }
    }
    CHECK(accepted > 0);
}

static void test_gate_dt_references(void)
{
    estimator_result_t r;
    uint64_t t;
    const float p0[3] = {0.0f, 0.0f, 1.0f};
    /* IMU mode: dt from the last prediction (20 ms) to the measurement (35 ms) = 15 ms */
    setup(EST_MODE_IMU, EST_STAGES_ALL, p0[0], p0[1], p0[2]);
    for (t = 0; t <= 25000; t += 1000) {
        CHECK(estimator_on_imu(&est, t, still_acc, no_gyro) == EST_OK);
    }
    CHECK(est.predictions == 2 && est.ekf.t_us == 20000);
    CHECK(estimator_on_twr(&est, 35000, 0, range_to(&est, 0, p0), &r) == EST_OK);
    CHECK_NEAR(r.d_max, 0.5 * 5000.0 * 0.015 * 0.015, 1e-5);
    /* UWB-only: first measurement dt_min, then the time since the previous state time */
    setup(EST_MODE_UWB_ONLY, EST_STAGES_ALL, p0[0], p0[1], p0[2]);
    CHECK(estimator_on_twr(&est, 7000000, 0, range_to(&est, 0, p0), &r) == EST_OK);
    CHECK_NEAR(r.d_max, 0.25, 1e-6);
    CHECK(est.predictions == 0);
    CHECK(estimator_on_twr(&est, 7030000, 0, range_to(&est, 0, p0), &r) == EST_OK);
    CHECK_NEAR(r.d_max, 0.5 * 5000.0 * 0.03 * 0.03, 1e-4);
    CHECK(est.predictions == 1);
}

static float dist3(const float a[3], const float b[3])
{
    const float dx = a[0] - b[0], dy = a[1] - b[1], dz = a[2] - b[2];
    return sqrtf(dx * dx + dy * dy + dz * dz);
}

static void test_robust_update(void)
{
    estimator_result_t r;
    float pos_plain[3], pos_robust[3], h;
    const float p0[3] = {0.5f, -0.5f, 1.0f};
    /* the weight: ~1 for a residual within the noise, R/w large for a gross one, bounded for NaN */
    CHECK_NEAR(robust_r_var(0.0f, 0.01f, 0.01f), 0.01f, 1e-9);
    CHECK(robust_r_var(0.05f, 0.01f, 0.01f) < 0.0102f);
    CHECK(robust_r_var(2.0f, 0.01f, 0.01f) > 10.0f * 0.01f);
    CHECK_NEAR(robust_r_var(NAN, 0.01f, 0.01f), 0.01f / ROBUST_W_MIN, 1e-3);
    CHECK(robust_r_var(-2.0f, 0.01f, 0.01f) == robust_r_var(2.0f, 0.01f, 0.01f));
    /* a converged filter (2 s of good ranges), then a 2 m outlier, no gates: the plain update follows it,
     * the robust one barely moves (with an uncertain prior it could not tell, and should not) */
    setup(EST_MODE_IMU, 0, p0[0], p0[1], p0[2]);
    run_static(p0, 2);
    h = range_to(&est, 7, p0);
    CHECK(estimator_on_twr(&est, 2001000u, 7, h + 2.0f, &r) == EST_OK);
    CHECK(r.status == EST_ACCEPTED);
    estimator_state(&est, pos_plain, NULL, NULL, NULL);
    setup(EST_MODE_IMU, EST_STAGE_ROBUST_UPDATE, p0[0], p0[1], p0[2]);
    run_static(p0, 2);
    CHECK(estimator_on_twr(&est, 2001000u, 7, h + 2.0f, &r) == EST_OK);
    CHECK(r.status == EST_ACCEPTED);
    estimator_state(&est, pos_robust, NULL, NULL, NULL);
    CHECK(dist3(pos_plain, p0) > 0.1f);
    CHECK(dist3(pos_robust, p0) < 0.2f * dist3(pos_plain, p0));
    CHECK(r.innovation_var > 10.0f * (0.25f * 0.25f)); /* S of the update carries the inflated R */
}

int main(void)
{
    RUN(test_statuses);
    RUN(test_gate_dt_references);
    RUN(test_chi2_lockout_guard);
    RUN(test_floor_range_keeps_the_guard_closed);
    RUN(test_robust_update);
    return UNIT_DONE();
}
