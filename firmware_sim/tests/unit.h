/* A tiny unit-test runner: CHECK* macros count failures; main() returns non-zero on any. */
#ifndef UWB_UNIT_H
#define UWB_UNIT_H

#include <math.h>
#include <stdio.h>

static int unit_failures;
static int unit_checks;

#define CHECK(cond) do { unit_checks++; if (!(cond)) { unit_failures++; \
    fprintf(stderr, "%s:%d: CHECK failed: %s\n", __FILE__, __LINE__, #cond); } } while (0)
#define CHECK_NEAR(a, b, tol) do { double a_ = (double)(a), b_ = (double)(b); unit_checks++; \
    if (!(fabs(a_ - b_) <= (double)(tol))) { unit_failures++; \
    fprintf(stderr, "%s:%d: CHECK_NEAR failed: %s = %.9g, %s = %.9g, tol %g\n", __FILE__, __LINE__, \
            #a, a_, #b, b_, (double)(tol)); } } while (0)
#define RUN(test) do { int f0_ = unit_failures; test(); \
    printf("  %-40s %s\n", #test, unit_failures == f0_ ? "ok" : "FAILED"); } while (0)
#define UNIT_DONE() (printf("%d checks, %d failed\n", unit_checks, unit_failures), unit_failures ? 1 : 0)

#endif
