/* replay_core: drive the estimator core from a text event stream, without the wire protocol.
 * Used by tests/unit/test_core_vs_twin.py to compare the C core with the numpy twin.
 *
 * Input lines (stdin), fields separated by blanks:
 *   C name=value ...            configure with reset: the power-up defaults with these CONFIG fields
 *                               (names of core/estimator_config.h's table) changed; "E 6" if invalid
 *   V name=value ...            only check such a configuration: prints "V 1" (valid) or "V 0"
 *   A id x y z                  anchor
 *   I t ax ay az gx gy gz       IMU sample (t in us)
 *   T t id range                TWR
 *   D t a b diff                TDoA, diff = d(tag, B) - d(tag, A)
 *   H t z std                   height pseudo-measurement
 * Output: one line per measurement,
 *   R status innovation S bias d_max gx gy gz px py pz vx vy vz qw qx qy qz var0..var8 flags
 * or "E code" for a refused input; a final "S predictions divergences heights" line.
 * Options: --no-model runs without the compiled-in bias networks; --fields prints "F name default" for
 * each configuration field and exits. */
#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "estimator.h"

static const bias_model_t no_model = {NULL, NULL, 0};

/* Defaults with the `name=value` pairs of s applied; 0 for an unknown name or a malformed value. */
static int parse_config(const char *line, estimator_config_t *c)
{
    static char s[4096];
    char *tok;
    estimator_default_config(c);
    strncpy(s, line, sizeof s - 1); /* strtok writes into it; the caller's line stays whole for messages */
    for (tok = strtok(s, " \t\r\n"); tok != NULL; tok = strtok(NULL, " \t\r\n")) {
        const char *eq = strchr(tok, '=');
        char *end;
        unsigned i;
        for (i = 0; eq != NULL && i < ESTIMATOR_CONFIG_N_FIELDS; i++) {
            const estimator_config_field_t *f = &estimator_config_fields[i];
            if (strlen(f->name) == (size_t)(eq - tok) && strncmp(f->name, tok, (size_t)(eq - tok)) == 0) {
                break;
            }
        }
        if (eq == NULL || i == ESTIMATOR_CONFIG_N_FIELDS) {
            return 0;
        }
        if (estimator_config_fields[i].is_float) {
            const float v = strtof(eq + 1, &end);
            memcpy((char *)c + estimator_config_fields[i].offset, &v, sizeof v);
        } else {
            const unsigned long v = strtoul(eq + 1, &end, 10);
            if (v > 255ul) {
                return 0;
            }
            *((uint8_t *)c + estimator_config_fields[i].offset) = (uint8_t)v;
        }
        if (end == eq + 1 || *end != '\0') {
            return 0;
        }
    }
    return 1;
}

static void print_fields(void)
{
    estimator_config_t d;
    unsigned i;
    estimator_default_config(&d);
    for (i = 0; i < ESTIMATOR_CONFIG_N_FIELDS; i++) {
        const estimator_config_field_t *f = &estimator_config_fields[i];
        if (f->is_float) {
            float v;
            memcpy(&v, (const char *)&d + f->offset, sizeof v);
            printf("F %s %.9g\n", f->name, (double)v);
        } else {
            printf("F %s %u\n", f->name, (unsigned)*((const uint8_t *)&d + f->offset));
        }
    }
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

/* The estimator's answer to one input: "E code" when it refused it, else the measurement's result (if any). */
static void answer(const estimator_t *est, int rc, const estimator_result_t *res)
{
    if (rc != EST_OK) {
        printf("E %d\n", rc);
    } else if (res != NULL) {
        print_result(est, res);
    }
}

/* A C or V line: configure with reset, or only check the configuration. */
static int config_line(estimator_t *est, const char *line)
{
    estimator_config_t cfg;
    if (!parse_config(line + 1, &cfg)) {
        return 0;
    }
    if (line[0] == 'V') {
        printf("V %d\n", estimator_config_valid(&cfg));
    } else if (!estimator_config_valid(&cfg)) {
        printf("E 6\n");
    } else {
        estimator_configure(est, &cfg, 1);
    }
    return 1;
}

/* One input line through the estimator; 0 when it cannot be parsed. */
static int handle_line(estimator_t *est, const char *line)
{
    estimator_result_t res;
    uint64_t t;
    unsigned id, ida, idb;
    float v[6];
    switch (line[0]) {
    case 'C':
    case 'V':
        return config_line(est, line);
    case 'A':
        if (sscanf(line + 1, "%u %f %f %f", &id, &v[0], &v[1], &v[2]) != 4) {
            return 0;
        }
        answer(est, estimator_set_anchor(est, (uint8_t)(id > 255 ? 255 : id), v), NULL);
        return 1;
    case 'I':
        if (sscanf(line + 1, "%" SCNu64 " %f %f %f %f %f %f", &t, &v[0], &v[1], &v[2], &v[3], &v[4], &v[5]) != 7) {
            return 0;
        }
        answer(est, estimator_on_imu(est, t, v, v + 3), NULL);
        return 1;
    case 'T':
        if (sscanf(line + 1, "%" SCNu64 " %u %f", &t, &id, &v[0]) != 3 || id > 255) {
            return 0;
        }
        answer(est, estimator_on_twr(est, t, (uint8_t)id, v[0], &res), &res);
        return 1;
    case 'D':
        if (sscanf(line + 1, "%" SCNu64 " %u %u %f", &t, &ida, &idb, &v[0]) != 4 || ida > 255 || idb > 255) {
            return 0;
        }
        answer(est, estimator_on_tdoa(est, t, (uint8_t)ida, (uint8_t)idb, v[0], &res), &res);
        return 1;
    case 'H':
        if (sscanf(line + 1, "%" SCNu64 " %f %f", &t, &v[0], &v[1]) != 3) {
            return 0;
        }
        answer(est, estimator_on_height(est, t, v[0], v[1]), NULL);
        return 1;
    case '\n':
    case '#':
        return 1;
    default:
        return 0;
    }
}

int main(int argc, char **argv)
{
    static estimator_t est;
    char line[4096];
    long lineno = 0;
    int i, with_model = 1;

    for (i = 1; i < argc; i++) {
        if (strcmp(argv[i], "--fields") == 0) {
            print_fields();
            return 0;
        }
        with_model = with_model && strcmp(argv[i], "--no-model") != 0;
    }
    estimator_init(&est, with_model ? &bias_model_compiled : &no_model);
    while (fgets(line, sizeof line, stdin) != NULL) {
        lineno++;
        if (!handle_line(&est, line)) {
            fprintf(stderr, "replay_core: cannot parse line %ld: %s", lineno, line);
            return 2;
        }
    }
    printf("S %" PRIu32 " %" PRIu32 " %" PRIu32 "\n", est.predictions, est.divergences, est.heights);
    return 0;
}
