/* Robust (M-estimation) scalar update: the measurement variance inflated by Cauchy weights of the
 * normalised post-update residual, iterated (IRLS). An alternative to the chi-square gate's
 * accept/reject: a measurement far from the estimate is not thrown away but barely moves it. */
#ifndef UWB_ROBUST_UPDATE_H
#define UWB_ROBUST_UPDATE_H

/* Cauchy constant (95 % efficiency under Gaussian noise), iterations, smallest weight. */
#define ROBUST_CAUCHY_C 2.3849f
#define ROBUST_ITERATIONS 3
#define ROBUST_W_MIN 1e-4f

/* R / w for innovation y, H P H^T = hph (>= 0) and nominal variance r_var (> 0). w starts at 1; each
 * iteration takes the residual the update with R / w would leave, e = y (R/w) / (hph + R/w), and sets
 * w = 1 / (1 + (e / (c sqrt(R)))^2), bounded below by ROBUST_W_MIN. NaN input gives r_var / W_MIN. */
float robust_r_var(float y, float hph, float r_var);

#endif
