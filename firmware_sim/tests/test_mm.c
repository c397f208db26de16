/* Measurement models: h and H at hand-checked points, H against central finite differences of h,
 * degenerate geometry (tag on an anchor, coinciding anchors, NaN) at the 1e-6 m boundary. */
#include "mm_kinds.h"
#include "mm_tdoa.h"
#include "mm_twr.h"
#include "unit.h"

static void test_twr_values(void)
{
    const float p[3] = {1.0f, 2.0f, 2.0f}, a[3] = {0.0f, 0.0f, 0.0f};
    const float p2[3] = {4.0f, 0.0f, 3.0f}, a2[3] = {1.0f, 4.0f, 3.0f};
    float h, H[3];
    CHECK(mm_twr(p, a, &h, H) == MM_OK);
    CHECK_NEAR(h, 3.0, 1e-6);
    CHECK_NEAR(H[0], 1.0 / 3.0, 1e-7);
    CHECK_NEAR(H[1], 2.0 / 3.0, 1e-7);
    CHECK_NEAR(H[2], 2.0 / 3.0, 1e-7);
    CHECK(mm_twr(p2, a2, &h, H) == MM_OK);
    CHECK_NEAR(h, 5.0, 1e-6);
    CHECK_NEAR(H[0], 0.6, 1e-7);
    CHECK_NEAR(H[1], -0.8, 1e-7);
    CHECK_NEAR(H[2], 0.0, 1e-7);
}

static void test_tdoa_values(void)
{
    /* p at the origin, A at (3,0,4) (5 m), B at (0,-1,0) (1 m): h = 1 - 5 = -4 */
    const float p[3] = {0.0f, 0.0f, 0.0f}, a[3] = {3.0f, 0.0f, 4.0f}, b[3] = {0.0f, -1.0f, 0.0f};
    float h, H[3];
    CHECK(mm_tdoa(p, a, b, &h, H) == MM_OK);
    CHECK_NEAR(h, -4.0, 1e-6);
    /* (p-b)/|p-b| = (0,1,0), (p-a)/|p-a| = (-0.6,0,-0.8) */
    CHECK_NEAR(H[0], 0.6, 1e-7);
    CHECK_NEAR(H[1], 1.0, 1e-7);
    CHECK_NEAR(H[2], 0.8, 1e-7);
    /* swapping A and B negates h and H */
    {
        float h2, H2[3];
        CHECK(mm_tdoa(p, b, a, &h2, H2) == MM_OK);
        CHECK_NEAR(h2, -h, 1e-6);
        CHECK_NEAR(H2[0], -H[0], 1e-7);
        CHECK_NEAR(H2[2], -H[2], 1e-7);
    }
}

/* Central differences in double around p for the model evaluated in float. */
static void check_fd(int tdoa, const float p[3], const float a[3], const float b[3])
{
    const float step = 1e-2f;
    float h, H[3];
    int k;
    CHECK((tdoa ? mm_tdoa(p, a, b, &h, H) : mm_twr(p, a, &h, H)) == MM_OK);
    for (k = 0; k < 3; k++) {
        float pp[3] = {p[0], p[1], p[2]}, pm[3] = {p[0], p[1], p[2]}, hp, hm, tmp[3];
        pp[k] += step;
        pm[k] -= step;
        CHECK((tdoa ? mm_tdoa(pp, a, b, &hp, tmp) : mm_twr(pp, a, &hp, tmp)) == MM_OK);
        CHECK((tdoa ? mm_tdoa(pm, a, b, &hm, tmp) : mm_twr(pm, a, &hm, tmp)) == MM_OK);
        /* O(step^2 / distance) truncation + float rounding */
        CHECK_NEAR(H[k], ((double)hp - (double)hm) / (2.0 * step), 2e-4);
    }
}

static void test_jacobians_vs_finite_differences(void)
{
    static const float pts[][3] = {{0.3f, -1.2f, 1.5f}, {2.5f, 3.0f, 0.2f}, {-3.0f, 0.1f, 2.9f}, {0.0f, 0.0f, 1.0f}};
    static const float anchors[][3] = {{-3.5f, -4.0f, 0.0f}, {3.5f, 4.0f, 3.0f}, {3.5f, -4.0f, 0.0f}, {-3.5f, 4.0f, 3.0f}};
    unsigned i, j;
    for (i = 0; i < 4; i++) {
        for (j = 0; j < 4; j++) {
            check_fd(0, pts[i], anchors[j], anchors[j]);
            check_fd(1, pts[i], anchors[j], anchors[(j + 1) % 4]);
        }
    }
}

static void test_degenerate_twr(void)
{
    const float a[3] = {1.0f, 2.0f, 3.0f};
    const float near_[3] = {0.0f, 0.0f, 5e-7f}, far_[3] = {0.0f, 0.0f, 2e-6f}, zero[3] = {0.0f, 0.0f, 0.0f};
    const float nan_p[3] = {NAN, 0.0f, 0.0f};
    float h = 1.0f, H[3] = {1.0f, 1.0f, 1.0f};
    CHECK(mm_twr(a, a, &h, H) == MM_DEGENERATE);
    CHECK(h == 0.0f && H[0] == 0.0f && H[1] == 0.0f && H[2] == 0.0f);
    CHECK(mm_twr(near_, zero, &h, H) == MM_DEGENERATE);  /* 0.5e-6 m < 1e-6 m */
    CHECK(mm_twr(far_, zero, &h, H) == MM_OK);           /* 2e-6 m: a direction exists */
    CHECK_NEAR(H[2], 1.0, 1e-6);
    CHECK(mm_twr(nan_p, zero, &h, H) == MM_DEGENERATE);
}

static void test_degenerate_tdoa(void)
{
    const float a[3] = {0.0f, 0.0f, 0.0f}, b[3] = {4.0f, 0.0f, 0.0f}, p[3] = {1.0f, 1.0f, 1.0f};
    float h = 1.0f, H[3] = {1.0f, 1.0f, 1.0f};
    CHECK(mm_tdoa(a, a, b, &h, H) == MM_DEGENERATE); /* tag on A */
    CHECK(h == 0.0f && H[0] == 0.0f && H[1] == 0.0f && H[2] == 0.0f);
    CHECK(mm_tdoa(b, a, b, &h, H) == MM_DEGENERATE); /* tag on B */
    CHECK(mm_tdoa(p, a, a, &h, H) == MM_DEGENERATE); /* A and B coincide: no information */
    CHECK(mm_tdoa(p, a, b, &h, H) == MM_OK);
}

/* TOF (mm_tof.c): the range along the body's -z axis from the ranger at tof_x/y/z to the floor; a sensor's
 * row (no anchor, its own std); tipped, out of range or NaN -> MM_DEGENERATE. */
static void test_tof_row(void)
{
    const mm_kind_t *row = mm_kind(MM_KIND_TOF);
    const float level[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
    const float c = 0.8f, s = 0.6f; /* rolled: cos 0.8 */
    const float rolled[3][3] = {{1, 0, 0}, {0, 0.8f, -0.6f}, {0, 0.6f, 0.8f}};
    const float p[3] = {0.3f, -0.2f, 1.0f};
    estimator_config_t cfg;
    mm_input_t in = {p, level, NULL, NULL, 0.9f, &cfg};
    float h, H[3];
    estimator_default_config(&cfg);
    cfg.tof_x = 0.02f;
    cfg.tof_y = 0.05f;
    cfg.tof_z = -0.1f;
    CHECK(row != NULL && row->n_anchors == 0 && row->net == MM_NO_NET && row->std_of != NULL);
    CHECK(row->model(&in, &h, H) == MM_OK);
    CHECK_NEAR(h, 0.9, 1e-6); /* 1.0 - 0.1, level */
    CHECK(H[0] == 0.0f && H[1] == 0.0f && H[2] == 1.0f);
    in.R = rolled; /* ranger at z = 1 + 0.6 * 0.05 + 0.8 * -0.1 = 0.95, range 0.95 / 0.8 */
    CHECK(row->model(&in, &h, H) == MM_OK);
    CHECK_NEAR(h, (1.0 + s * 0.05 - c * 0.1) / c, 1e-6);
    CHECK_NEAR(H[2], 1.0 / c, 1e-6);
    CHECK_NEAR(row->std_of(&in), cfg.std_tof * (1.0 + exp(2.9213 * (0.9 - 2.5))), 1e-7);
    in.z = 0.0f; /* on the floor */
    CHECK(row->model(&in, &h, H) == MM_OK);
    in.z = 5.0f; /* beyond the ranger's limit */
    CHECK(row->model(&in, &h, H) == MM_DEGENERATE);
    in.z = -0.01f;
    CHECK(row->model(&in, &h, H) == MM_DEGENERATE);
    in.z = NAN;
    CHECK(row->model(&in, &h, H) == MM_DEGENERATE);
    in.z = 0.9f;
    cfg.tof_z = NAN;
    CHECK(row->model(&in, &h, H) == MM_DEGENERATE && h == 0.0f && H[2] == 0.0f);
}

int main(void)
{
    RUN(test_twr_values);
    RUN(test_tdoa_values);
    RUN(test_jacobians_vs_finite_differences);
    RUN(test_degenerate_twr);
    RUN(test_degenerate_tdoa);
    RUN(test_tof_row);
    return UNIT_DONE();
}
