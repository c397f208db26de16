/* replay_core: drive the estimator core from a text event stream, without the wire protocol.
 * Used by tests/test_core_vs_twin.py to compare the C core with the numpy twin.
 *
 * Input lines (stdin), fields separated by blanks:
 *   C mode stages std_twr std_tdoa a_max_twr a_max_tdoa gate_dt_min chi2_twr chi2_tdoa
 *     proc_acc_xy proc_acc_z proc_cv_acc init_x init_y init_z init_std_xy init_std_z nn_min_z
 *     sup_margin sup_max_speed sup_max_var
 *                               configure with reset (prints "E 6" if invalid)
 *   A id x y z                  anchor
 *   I t ax ay az gx gy gz       IMU sample (t in us)
 *   T t id range                TWR
 *   D t a b diff                TDoA, diff = d(tag, B) - d(tag, A)
 *   H t z std                   height pseudo-measurement
 * Output: one line per measurement,
 *   R status innovation S bias d_max gx gy gz px py pz vx vy vz qw qx qy qz var0..var8 flags
 * or "E code" for a refused input; a final "S predictions divergences heights" line.
 * Option --no-model runs without the compiled-in bias networks. */
#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "estimator.h"

static const bias_model_t no_model = {NULL, NULL, 0};

static int parse_config(const char *s, estimator_config_t *c)
{
    unsigned mode, stages;
    int n = sscanf(s, "%u %u %f %f %f %f %f %f %f %f %f %f %f %f %f %f %f %f %f %f %f", &mode, &stages,
                   &c->std_twr, &c->std_tdoa, &c->a_max_twr, &c->a_max_tdoa, &c->gate_dt_min,
                   &c->chi2_twr, &c->chi2_tdoa, &c->proc_acc_xy, &c->proc_acc_z, &c->proc_cv_acc,
                   &c->init_x, &c->init_y, &c->init_z, &c->init_std_xy, &c->init_std_z, &c->nn_min_z,
                   &c->sup_margin, &c->sup_max_speed, &c->sup_max_var);
    c->mode = (uint8_t)mode;
    c->stages = (uint8_t)stages;
    return n == 21 && mode < 256 && stages < 256;
}

static void print_result(const estimator_t *est, const estimator_result_t *r)
{
    float pos[3], vel[3], quat[4], var[9];
    int i;
    estimator_state(est, pos, vel, quat, var);
    printf("R %u %.9g %.9g %.9g %.9g %.9g %.9g %.9g", (unsigned)r->status, (double)r->innovation,
           (double)r->innovation_var, (double)r->bias, (double)r->d_max, (double)r->gain[0],
           (double)r->gain[1], (double)r->gain[2]);
    for (i = 0; i < 3; i++) {
        printf(" %.9g", (double)pos[i]);
    }
    for (i = 0; i < 3; i++) {
        printf(" %.9g", (double)vel[i]);
    }
    for (i = 0; i < 4; i++) {
        printf(" %.9g", (double)quat[i]);
    }
    for (i = 0; i < 9; i++) {
        printf(" %.9g", (double)var[i]);
    }
    printf(" %u\n", (unsigned)r->flags);
}

int main(int argc, char **argv)
{
    static estimator_t est;
    char line[512];
    estimator_result_t res;
    long lineno = 0;
    int rc;

    estimator_init(&est, (argc > 1 && strcmp(argv[1], "--no-model") == 0) ? &no_model : &bias_model_compiled);
    while (fgets(line, sizeof line, stdin) != NULL) {
        uint64_t t;
        unsigned id, ida, idb;
        float v[6];
        lineno++;
        switch (line[0]) {
        case 'C': {
            estimator_config_t cfg;
            if (!parse_config(line + 1, &cfg) || !estimator_config_valid(&cfg)) {
                printf("E 6\n");
            } else {
                estimator_configure(&est, &cfg, 1);
            }
            break;
        }
        case 'A':
            if (sscanf(line + 1, "%u %f %f %f", &id, &v[0], &v[1], &v[2]) != 4) {
                goto bad;
            }
            rc = estimator_set_anchor(&est, (uint8_t)(id > 255 ? 255 : id), v);
            if (rc != EST_OK) {
                printf("E %d\n", rc);
            }
            break;
        case 'I':
            if (sscanf(line + 1, "%" SCNu64 " %f %f %f %f %f %f", &t, &v[0], &v[1], &v[2], &v[3], &v[4],
                       &v[5]) != 7) {
                goto bad;
            }
            rc = estimator_on_imu(&est, t, v, v + 3);
            if (rc != EST_OK) {
                printf("E %d\n", rc);
            }
            break;
        case 'T':
            if (sscanf(line + 1, "%" SCNu64 " %u %f", &t, &id, &v[0]) != 3 || id > 255) {
                goto bad;
            }
            rc = estimator_on_twr(&est, t, (uint8_t)id, v[0], &res);
            if (rc == EST_OK) {
                print_result(&est, &res);
            } else {
                printf("E %d\n", rc);
            }
            break;
        case 'D':
            if (sscanf(line + 1, "%" SCNu64 " %u %u %f", &t, &ida, &idb, &v[0]) != 4 || ida > 255 || idb > 255) {
                goto bad;
            }
            rc = estimator_on_tdoa(&est, t, (uint8_t)ida, (uint8_t)idb, v[0], &res);
            if (rc == EST_OK) {
                print_result(&est, &res);
            } else {
                printf("E %d\n", rc);
            }
            break;
        case 'H':
            if (sscanf(line + 1, "%" SCNu64 " %f %f", &t, &v[0], &v[1]) != 3) {
                goto bad;
            }
            rc = estimator_on_height(&est, t, v[0], v[1]);
            if (rc != EST_OK) {
                printf("E %d\n", rc);
            }
            break;
        case '\n':
        case '#':
            break;
        default:
            goto bad;
        }
        continue;
    bad:
        fprintf(stderr, "replay_core: cannot parse line %ld: %s", lineno, line);
        return 2;
    }
    printf("S %" PRIu32 " %" PRIu32 " %" PRIu32 "\n", est.predictions, est.divergences, est.heights);
    return 0;
}
