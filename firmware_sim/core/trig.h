/* sin, cos, tan and exp in float for the estimator and the controller: small own versions instead of newlib's
 * (whose large-argument reduction alone is 2.4 KB of flash). Every finite argument is reduced correctly:
 * |x| < 6,000 rad (every argument the firmware passes: half rotation angles, yaw, tilt limit) by a
 * three-part pi/2 whose products with the quadrant are exact, larger ones through a 64-bit window of
 * 2/pi's bits; then Taylor polynomials of degree 9 (sin) and 10 (cos) on [-pi/4, pi/4].
 * Max error against sin/cos in double (tests/test_trig.c): 1.8 float ulps for |x| <= 8, 2.4 beyond (the
 * reduced argument is rounded twice); 2 ulps from glibc's sinf/cosf;
 * non-finite arguments give NaN. */
#ifndef UWB_TRIG_H
#define UWB_TRIG_H

float trig_sinf(float x);
float trig_cosf(float x);
float trig_tanf(float x);

/* e^x within 1.2 float ulps of exp in double for every normal result (tests/test_trig.c): the bias states'
 * decay, the network's std head and the ToF std, on the host and the MCU alike; newlib's expf was ~50
 * instructions a call on the M4 and 0.5 KB of flash. NaN for NaN, +inf above 89, 0 below -104. */
float trig_expf(float x);

#endif
